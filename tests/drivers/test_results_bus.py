"""FrictionResults (J1939 PGN 0xFF20) onto python-can's virtual bus, decoded back with cantools and the shipped DBC."""

from __future__ import annotations

import itertools
import math
import time
from collections import Counter

import can
import numpy as np
import pytest
from frictionwatch.drivers.can.codec import j1939_pgn, load_dbc
from frictionwatch.drivers.can.results_bus import ResultsPublisher, decode_results, encode_results
from hypothesis import given, settings
from hypothesis import strategies as st

_channels = itertools.count()


def test_round_trip_on_the_virtual_bus() -> None:
    channel = f"fw-results-{next(_channels)}-{time.monotonic_ns()}"
    rng = np.random.default_rng(11)
    fmep = rng.uniform(1.2, 2.4, 20)  # genset-v20: about 1.8 bar (engines.md §4)
    alerts = [0] * 20
    alerts[6], alerts[13] = 1, 2
    with can.Bus(interface="virtual", channel=channel) as tx, can.Bus(interface="virtual", channel=channel) as rx:
        pub = ResultsPublisher(tx, enabled=True)
        assert pub.publish(fmep, alerts, 1790.25) == 9  # summary + alerts + 7 FMEP pages
        assert pub.publish(fmep, alerts, 1790.25) == 9
        got = []
        while (m := rx.recv(timeout=0.2)) is not None:
            got.append(m)
    assert len(got) == 18 and all(m.is_extended_id and j1939_pgn(m.arbitration_id) == 0xFF20 for m in got)
    db = load_dbc()
    pages = [db.decode_message(m.arbitration_id, m.data, decode_choices=False) for m in got[:9]]
    assert pages[0]["FrictionTorque"] == pytest.approx(1790.25, abs=0.005)  # 0.01 N m resolution
    assert [pages[1][f"RingAlert_C{k:02d}"] for k in range(1, 21)] == alerts
    fmep_cantools = [pages[2 + (k - 1) // 3][f"FMEP_C{k:02d}"] for k in range(1, 21)]
    np.testing.assert_allclose(fmep_cantools, fmep, rtol=0, atol=0.0005)  # 0.001 bar resolution
    sets = decode_results(got)
    assert [s.result_seq for s in sets] == [0, 1] and sets[0].source_address == 0x80
    np.testing.assert_allclose(sets[1].fmep_bar, fmep, rtol=0, atol=0.0005)
    assert sets[1].alert_state == tuple(alerts) and sets[1].friction_torque_nm == pytest.approx(1790.25, abs=0.005)


def test_nan_out_of_range_and_sizes() -> None:
    msgs = encode_results([1.5, math.nan, 99.0, -0.2], [0, 3, 2, 1], math.nan, result_seq=300)
    (s,) = decode_results(msgs)
    assert s.result_seq == 300 % 256 and math.isnan(s.friction_torque_nm)
    assert s.fmep_bar[0] == pytest.approx(1.5) and math.isnan(s.fmep_bar[1]) and math.isnan(s.fmep_bar[2])
    assert s.fmep_bar[3] == pytest.approx(-0.2)  # negative FMEP estimates are sent as they are
    assert [len(encode_results([1.0] * z, [0] * z, 1.0)) for z in (1, 3, 4, 24)] == [3, 3, 4, 10]
    for bad in (([], [], 1.0), ([1.0] * 25, [0] * 25, 1.0), ([1.0], [0, 0], 1.0), ([1.0], [4], 1.0)):
        with pytest.raises(ValueError):
            encode_results(*bad)


def test_off_by_default_and_send_errors_counted() -> None:
    assert ResultsPublisher().publish([1.0], [0], 1.0) == 0
    channel = f"fw-results-{next(_channels)}-{time.monotonic_ns()}"
    with can.Bus(interface="virtual", channel=channel) as bus:
        assert ResultsPublisher(bus).publish([1.0], [0], 1.0) == 0  # a bus alone does not switch it on

        class Full:
            def send(self, msg: can.Message, timeout: float | None = None) -> None:
                raise can.CanOperationError("TX buffer full")

        pub = ResultsPublisher(Full(), enabled=True)  # type: ignore[arg-type]
        assert pub.publish([1.0, 2.0], [0, 0], 5.0) == 0 and pub.damage["results_send_failed"] == 3


def test_incomplete_and_foreign_frames_counted() -> None:
    msgs = encode_results([1.0] * 6, [0] * 6, 10.0, result_seq=1)
    damage: Counter[str] = Counter()
    foreign = can.Message(arbitration_id=0x0CF00400, is_extended_id=True, data=bytes(8))
    short = can.Message(arbitration_id=msgs[0].arbitration_id, is_extended_id=True, data=bytes(4))
    assert decode_results([foreign, short] + msgs[:-1], damage) == []
    assert damage == {"wrong_dlc": 1, "incomplete_result_set": 1}


@settings(max_examples=60, deadline=None, derandomize=True)
@given(st.lists(st.tuples(st.floats(-10, 54.2, allow_nan=False), st.integers(0, 3)), min_size=1, max_size=24),
       st.floats(-1e6, 1e6, allow_nan=False), st.integers(0, 1000))
def test_fuzz_round_trip(cyl: list, torque: float, seq: int) -> None:
    fmep = [f for f, _ in cyl]
    alerts = [a for _, a in cyl]
    (s,) = decode_results(encode_results(fmep, alerts, torque, result_seq=seq))
    np.testing.assert_allclose(s.fmep_bar, fmep, rtol=0, atol=0.0005 + 1e-9)
    assert s.alert_state == tuple(alerts) and s.friction_torque_nm == pytest.approx(torque, abs=0.005 + 1e-9)


@settings(max_examples=60, deadline=None, derandomize=True)
@given(st.lists(st.binary(min_size=0, max_size=9), max_size=30))
def test_fuzz_random_result_frames(payloads: list[bytes]) -> None:
    msgs = [can.Message(arbitration_id=0x18FF2080, is_extended_id=True, data=p) for p in payloads]
    for s in decode_results(msgs):
        assert len(s.alert_state) == s.fmep_bar.size
