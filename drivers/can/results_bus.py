"""Results back onto the bus (optional, off by default): J1939 proprietary B PGN 0xFF20 ``FrictionResults``.

One result set per engine cycle = page 0 (total friction torque, cylinder count), page 1 (ring-alert state of up to
24 cylinders, 2 bits each) and pages 2.. (FMEP of 3 cylinders each), all with the same ``ResultSeq`` so a reader
can tell the pages of one set apart. The layout is in drivers/can/frictionwatch.dbc; a genset controller or SCADA gateway
reads it with that DBC and no HTTP. No standard J1939 parameter exists per cylinder (SPN 514 "Nominal Friction -
Percent Torque" is whole-engine only), hence a proprietary PGN.

This module knows numbers, not friction: FMEP in bar per cylinder, alert states as ints, torque in N m.
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import can
import cantools
import numpy as np
from frictionwatch.drivers.can.codec import (
    J1939_PRIORITY,
    PGN_RESULTS,
    SA_MONITOR,
    j1939_id,
    j1939_pgn,
    j1939_raw,
    j1939_value,
    layouts,
)

log = logging.getLogger(__name__)

ALERT_NORMAL, ALERT_WARNING, ALERT_ALARM, ALERT_NOT_AVAILABLE = 0, 1, 2, 3
PAGE_SUMMARY, PAGE_ALERTS, PAGE_FMEP0 = 0, 1, 2
CYL_PER_PAGE = 3


def _max_cylinders() -> int:
    return layouts().cylinders


def encode_results(fmep_bar: Sequence[float], alert_state: Sequence[int], friction_torque_nm: float, *,
                   result_seq: int = 0, source_address: int = SA_MONITOR,
                   priority: int = J1939_PRIORITY) -> list[can.Message]:
    """The pages of one result set.

    Parameters
    ----------
    fmep_bar : sequence of float
        FMEP per cylinder [bar], cylinder 1 first; NaN -> 'not available', outside -10..54.25 bar -> 'error'.
    alert_state : sequence of int
        Ring-alert state per cylinder: 0 normal, 1 warning, 2 alarm, 3 not available.
    friction_torque_nm : float
        Total friction torque of the engine [N m] (NaN -> 'not available').
    result_seq : int
        Set counter (mod 256), the same in every page of the set.
    """
    z = len(fmep_bar)
    if not 1 <= z <= _max_cylinders():
        raise ValueError(f"1..{_max_cylinders()} cylinders fit the FrictionResults PGN, got {z}")
    if len(alert_state) != z:
        raise ValueError(f"alert_state has {len(alert_state)} entries for {z} cylinders")
    states = [int(s) for s in alert_state]
    if any(not 0 <= s <= 3 for s in states):
        raise ValueError("alert states are 0 normal, 1 warning, 2 alarm, 3 not available")
    msg = layouts().results
    fid = j1939_id(PGN_RESULTS, source_address, priority)
    seq = result_seq & 0xFF
    pages = [{"Page": PAGE_SUMMARY, "ResultSeq": seq, "CylinderCount": z,
              "FrictionTorque": j1939_raw(msg, "FrictionTorque", float(friction_torque_nm))},
             {"Page": PAGE_ALERTS, "ResultSeq": seq,
              **{f"RingAlert_C{k:02d}": (states[k - 1] if k <= z else ALERT_NOT_AVAILABLE)
                 for k in range(1, _max_cylinders() + 1)}}]
    for p in range(math.ceil(z / CYL_PER_PAGE)):
        ks = range(p * CYL_PER_PAGE + 1, p * CYL_PER_PAGE + CYL_PER_PAGE + 1)
        pages.append({"Page": PAGE_FMEP0 + p, "ResultSeq": seq,
                      **{f"FMEP_C{k:02d}": j1939_raw(msg, f"FMEP_C{k:02d}", float(fmep_bar[k - 1]) if k <= z
                                                     else math.nan) for k in ks}})
    return [can.Message(arbitration_id=fid, is_extended_id=True,
                        data=msg.encode(page, scaling=False, padding=True, strict=False)) for page in pages]


@dataclass(frozen=True)
class ResultSet:
    """One decoded result set (NaN where the sender had no valid value)."""

    result_seq: int
    source_address: int
    friction_torque_nm: float
    fmep_bar: np.ndarray
    alert_state: tuple[int, ...]


def decode_results(messages: Iterable[can.Message], damage: Counter[str] | None = None) -> list[ResultSet]:
    """Complete result sets found in ``messages`` (other frames ignored; incomplete sets counted in ``damage``)."""
    msg = layouts().results
    damage = Counter() if damage is None else damage
    sets: dict[tuple[int, int], dict[int, dict[str, int]]] = {}
    order: list[tuple[int, int]] = []
    for m in messages:
        if not m.is_extended_id or j1939_pgn(m.arbitration_id) != PGN_RESULTS:
            continue
        if len(m.data) != 8:
            damage["wrong_dlc"] += 1
            continue
        try:
            raw = msg.decode(bytes(m.data), decode_choices=False, scaling=False)
        except cantools.database.errors.DecodeError:  # e.g. a page number the DBC does not define
            damage["undecodable_results_page"] += 1
            continue
        key = (m.arbitration_id & 0xFF, int(raw["ResultSeq"]))
        if key not in sets:
            sets[key] = {}
            order.append(key)
        sets[key][int(raw["Page"])] = raw
    out = []
    for key in order:
        pages = sets[key]
        z = int(pages.get(PAGE_SUMMARY, {}).get("CylinderCount", 0))
        need = {PAGE_SUMMARY, PAGE_ALERTS, *range(PAGE_FMEP0, PAGE_FMEP0 + math.ceil(z / CYL_PER_PAGE))}
        if z == 0 or not need <= pages.keys():
            damage["incomplete_result_set"] += 1
            continue
        fmep = np.array([j1939_value(msg, f"FMEP_C{k:02d}",
                                     pages[PAGE_FMEP0 + (k - 1) // CYL_PER_PAGE][f"FMEP_C{k:02d}"])[0]
                         for k in range(1, z + 1)])
        torque = j1939_value(msg, "FrictionTorque", pages[PAGE_SUMMARY]["FrictionTorque"])[0]
        alerts = tuple(int(pages[PAGE_ALERTS][f"RingAlert_C{k:02d}"]) for k in range(1, z + 1))
        out.append(ResultSet(key[1], key[0], torque, fmep, alerts))
    return out


class ResultsPublisher:
    """Sends a result set per call when ``enabled`` (off by default); send errors are counted, never raised."""

    def __init__(self, bus: can.BusABC | None = None, *, enabled: bool = False,
                 source_address: int = SA_MONITOR) -> None:
        self.bus = bus
        self.enabled = enabled and bus is not None
        self.source_address = source_address
        self.result_seq = 0
        self.damage: Counter[str] = Counter()

    def publish(self, fmep_bar: Sequence[float], alert_state: Sequence[int], friction_torque_nm: float) -> int:
        """Send one set; returns the number of frames sent (0 when disabled or on a bus error)."""
        if not self.enabled or self.bus is None:
            return 0
        frames = encode_results(fmep_bar, alert_state, friction_torque_nm, result_seq=self.result_seq,
                                source_address=self.source_address)
        self.result_seq = (self.result_seq + 1) & 0xFF
        sent = 0
        for frame in frames:
            try:
                self.bus.send(frame, timeout=0.01)
                sent += 1
            except (can.CanError, OSError) as exc:
                if not self.damage["results_send_failed"]:
                    log.warning("results frame not sent: %s", exc)
                self.damage["results_send_failed"] += 1
        return sent
