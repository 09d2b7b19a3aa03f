"""The shipped DBC, the numpy layouts derived from it (checked against cantools frame by frame), and the encoders."""

from __future__ import annotations

import math

import numpy as np
import pytest
from frictionwatch.drivers.can.codec import (
    FD_SAMPLES,
    PGN_LOAD,
    RAW_INVALID,
    RAW_SATURATED,
    encode_load,
    encode_pressure_classic,
    encode_pressure_fd,
    encode_pressure_ref,
    fd_scale_for,
    j1939_id,
    j1939_pgn,
    j1939_status,
    layouts,
    load_dbc,
)
from frictionwatch.drivers.can.encoder import PressureEncoder


def test_dbc_ships_and_fits_the_fast_decoder() -> None:
    db = load_dbc()
    lay = layouts()
    assert lay.cylinders == 24 and len(lay.ref_id) == len(lay.classic_id) == 24
    fd = db.get_message_by_name("PressureFD_C20")
    assert fd.is_fd and fd.length == 64 and not fd.is_extended_frame and fd.frame_id == 0x113
    load = db.get_message_by_name("GensetLoad")
    assert load.is_extended_frame and load.protocol == "j1939" and j1939_pgn(load.frame_id) == PGN_LOAD
    assert lay.fd_dtype.itemsize == 64 and lay.fd_dtype["samples"].shape == (FD_SAMPLES,)
    assert lay.fd_period_factor == 2.0 ** -16 and lay.fd_scale_factor == pytest.approx(0.1)


def test_j1939_identifiers() -> None:
    assert j1939_pgn(0x0CF00400) == 0xF004  # EEC1 from the engine (SA 0), priority 3
    assert j1939_pgn(0x18EAFF00) == 0xEA00  # PDU1 request: destination byte is not part of the PGN
    assert j1939_id(0xFF10, 0xEA) == 0x18FF10EA
    assert [j1939_status(r, 16) for r in (0xFAFF, 0xFB00, 0xFE12, 0xFFFF)] == [None, "reserved", "error",
                                                                                "not_available"]


def test_fd_layout_matches_cantools_frame_by_frame() -> None:
    rng = np.random.default_rng(7)
    db = load_dbc()
    lay = layouts()
    for k in range(40):
        cyl = int(rng.integers(1, 25))
        n = int(rng.integers(1, FD_SAMPLES + 1))
        values = rng.uniform(-2e5, 2.5e7, n)
        msg = encode_pressure_fd(cyl, int(rng.integers(0, 65536)), int(rng.integers(0, 2**32)),
                                 float(rng.uniform(1, 4000)), values, sensor_fault=k % 3 == 0, daq_overrun=k % 4 == 0,
                                 restart=k % 5 == 0)
        ref = db.decode_message(msg.arbitration_id, msg.data, decode_choices=False)
        rec = np.frombuffer(bytes(msg.data), lay.fd_dtype)[0]
        assert db.get_message_by_frame_id(msg.arbitration_id).name == f"PressureFD_C{cyl:02d}"
        assert (rec["Seq"], rec["T0Ticks"], rec["NSamples"]) == (ref["Seq"], ref["T0Ticks"], ref["NSamples"])
        assert rec["PeriodTicks"] * lay.fd_period_factor == pytest.approx(ref["PeriodTicks"], abs=1e-9)
        assert rec["Scale"] * lay.fd_scale_factor == pytest.approx(ref["Scale"], abs=1e-9)
        for name, bit in lay.fd_flag_bits.items():
            assert (rec["Flags"] >> bit) & 1 == ref[name]
        np.testing.assert_array_equal(rec["samples"], [ref[f"S{i:02d}"] for i in range(FD_SAMPLES)])
        # quantisation: half a count of the per-frame scale (scale chosen so the peak fits 32766 counts)
        np.testing.assert_allclose(rec["samples"][:n] * ref["Scale"], values, rtol=0, atol=ref["Scale"] / 2 + 1e-6)


def test_classic_layouts_match_cantools() -> None:
    db = load_dbc()
    lay = layouts()
    ref_msg = encode_pressure_ref(4, 65535, 2**32 - 1, 2000)
    assert db.decode_message(ref_msg.arbitration_id, ref_msg.data) == {"Seq": 65535, "T0Ticks": 2**32 - 1,
                                                                       "PeriodTicks": 2000}
    data = encode_pressure_classic(4, 9, [1.0e5, 150.4e5, np.nan])
    dec = db.decode_message(data.arbitration_id, data.data)
    rec = np.frombuffer(bytes(data.data), lay.classic_dtype)[0]
    assert dec["Seq"] == rec["Seq"] == 9
    assert [dec["S0"], dec["S1"], dec["S2"]] == pytest.approx([1.0e5, 150.4e5, RAW_INVALID * 1000.0])
    np.testing.assert_array_equal(rec["samples"], [100, 15040, RAW_INVALID])


def test_saturation_nan_and_scale_rules() -> None:
    lay = layouts()
    values = np.array([1e5, np.nan, 3e5, 2.0e5])
    msg = encode_pressure_fd(1, 0, 0, 500.0, values, saturated=[False, False, False, True])
    rec = np.frombuffer(bytes(msg.data), lay.fd_dtype)[0]
    np.testing.assert_array_equal(rec["samples"][[1, 3]], [RAW_INVALID, RAW_SATURATED])
    assert fd_scale_for(np.array([32766 * 100.0])) == pytest.approx(100.0)
    over = encode_pressure_fd(1, 0, 0, 500.0, [1e5, 5e7], scale_pa=100.0)  # 5e7 Pa does not fit 100 Pa/count
    assert np.frombuffer(bytes(over.data), lay.fd_dtype)[0]["samples"][1] == RAW_SATURATED
    with pytest.raises(ValueError):
        encode_pressure_fd(1, 0, 0, 500.0, np.ones(26))
    with pytest.raises(ValueError):
        encode_pressure_fd(25, 0, 0, 500.0, np.ones(3))  # no such cylinder in the DBC
    with pytest.raises(ValueError):
        encode_pressure_ref(1, 0, 0, 208.5)  # classic CAN needs an integer period
    with pytest.raises(ValueError):
        PressureEncoder(fd=False).block(1, 0, 208.5, np.ones(6))


def test_load_frame_and_not_available() -> None:
    db = load_dbc()
    msg = encode_load(3.33e6, 21_200.0, counter=260)
    assert msg.is_extended_id and msg.arbitration_id == 0x18FF10EA and msg.data[7] == 0xFF  # J1939 padding
    assert db.decode_message(msg.arbitration_id, msg.data) == {"RealPower": 3_330_000, "ShaftTorque": 21_200,
                                                               "Counter": 4}
    na = encode_load(math.nan, math.nan)
    raw = db.get_message_by_name("GensetLoad").decode(na.data, scaling=False)
    assert (raw["RealPower"], raw["ShaftTorque"]) == (0xFFFFFFFF, 0xFFFF)
    err = db.get_message_by_name("GensetLoad").decode(encode_load(1e6, 1e6).data, scaling=False)
    assert j1939_status(err["ShaftTorque"], 16) == "error"  # 1 MN m does not fit: sent as 'error', not clipped
