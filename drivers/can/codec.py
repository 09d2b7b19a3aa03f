"""frictionwatch CAN frames (docs/protocols.md §3): the shipped DBC, the byte layouts derived from it, and encoders.

The DBC (drivers/can/frictionwatch.dbc, loaded with cantools) is the single source of truth. For the 16,000 pressure
frames/s of a 20-cylinder engine a per-frame ``cantools.decode_message`` is too slow (tens of µs per frame), so
``Layouts`` reads each message's signal positions, factors and signedness from the DBC once and builds numpy
structured dtypes that decode whole batches at once; tests check both against cantools frame by frame.

J1939 messages (GensetLoad PGN 0xFF10, FrictionResults PGN 0xFF20) are matched by PGN whatever the source address.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from importlib import resources

import can
import cantools
import numpy as np

FD_SAMPLES = 25
CLASSIC_SAMPLES = 3
RAW_SATURATED = 32767  # ADC at full scale
RAW_INVALID = -32768  # no valid sample (NaN at the sender, sensor fault)
FLAG_SENSOR_FAULT, FLAG_DAQ_OVERRUN, FLAG_RESTART = "SensorFault", "DaqOverrun", "Restart"
PGN_LOAD, PGN_RESULTS = 0xFF10, 0xFF20
SA_GENSET, SA_MONITOR = 0xEA, 0x80
J1939_PRIORITY = 6


@functools.cache
def load_dbc() -> cantools.database.can.Database:
    """The shipped frictionwatch DBC (package data of ``drivers``)."""
    text = resources.files("frictionwatch.drivers.can").joinpath("frictionwatch.dbc").read_text(encoding="utf-8")
    return cantools.database.load_string(text, database_format="dbc")


def j1939_id(pgn: int, source_address: int, priority: int = J1939_PRIORITY) -> int:
    """29-bit identifier of a PDU2 (broadcast) J1939 message."""
    return ((priority & 7) << 26) | ((pgn & 0x3FFFF) << 8) | (source_address & 0xFF)


def j1939_pgn(can_id: np.ndarray | int) -> np.ndarray | int:
    """PGN of 29-bit identifiers (PDU1 PGNs lose their destination address byte)."""
    pgn = (np.asarray(can_id, dtype=np.int64) >> 8) & 0x3FFFF
    pgn = np.where(((pgn >> 8) & 0xFF) < 240, pgn & 0x3FF00, pgn)
    return int(pgn) if np.ndim(pgn) == 0 else pgn


def byte_field(msg: cantools.database.can.Message, name: str) -> tuple[int, str, float, float]:
    """(byte offset, numpy dtype, factor, offset) of a byte-aligned little-endian signal."""
    sig = msg.get_signal_by_name(name)
    if sig.byte_order != "little_endian" or sig.start % 8 or sig.length not in (8, 16, 32):
        raise ValueError(f"{msg.name}.{name}: the fast decoder needs byte-aligned Intel signals of 8/16/32 bits")
    return sig.start // 8, f"<{'i' if sig.is_signed else 'u'}{sig.length // 8}", float(sig.scale), float(sig.offset)


@dataclass(frozen=True)
class Layouts:
    """Byte layouts, factors and identifiers read from the DBC (see ``layouts()``)."""

    fd_dtype: np.dtype
    fd_period_factor: float
    fd_scale_factor: float
    fd_flag_bits: dict[str, int]  # flag name -> bit in the flags byte
    ref_dtype: np.dtype
    classic_dtype: np.dtype
    classic_factor: float  # Pa per count of the classic samples
    fd_id: dict[int, int]  # frame id -> cylinder
    ref_id: dict[int, int]
    classic_id: dict[int, int]
    cylinders: int
    load: cantools.database.can.Message
    results: cantools.database.can.Message

    def id_of(self, kind: str, cylinder: int) -> int:
        table = {"fd": self.fd_id, "ref": self.ref_id, "classic": self.classic_id}[kind]
        for fid, cyl in table.items():
            if cyl == cylinder:
                return fid
        raise ValueError(f"cylinder {cylinder} not in the DBC (1..{self.cylinders})")


def _struct(msg: cantools.database.can.Message, names: list[str], samples: list[str], size: int) -> np.dtype:
    fields = {n: byte_field(msg, n) for n in names}
    first = byte_field(msg, samples[0])
    for i, s in enumerate(samples):  # samples must be a contiguous array of one type
        off, dt, _, _ = byte_field(msg, s)
        if off != first[0] + i * np.dtype(first[1]).itemsize or dt != first[1]:
            raise ValueError(f"{msg.name}: samples are not a contiguous {first[1]} array")
    return np.dtype({"names": [*names, "samples"],
                     "formats": [fields[n][1] for n in names] + [(first[1], len(samples))],
                     "offsets": [fields[n][0] for n in names] + [first[0]], "itemsize": size})


@functools.cache
def layouts() -> Layouts:
    """Read and check the layouts once (raises ValueError if the DBC no longer fits the fast decoder)."""
    db = load_dbc()
    fd_id, ref_id, classic_id = {}, {}, {}
    for msg in db.messages:
        for prefix, table in (("PressureFD_C", fd_id), ("PressureRef_C", ref_id), ("PressureClassic_C", classic_id)):
            if msg.name.startswith(prefix):
                table[msg.frame_id] = int(msg.name[len(prefix):])
    fd = db.get_message_by_name("PressureFD_C01")
    flags_byte = fd.get_signal_by_name(FLAG_SENSOR_FAULT).start // 8
    fd_dtype = _struct(fd, ["Seq", "T0Ticks", "PeriodTicks", "Scale", "NSamples"],
                       [f"S{i:02d}" for i in range(FD_SAMPLES)], 64)
    fd_dtype = _with_flags(fd_dtype, flags_byte)
    ref = db.get_message_by_name("PressureRef_C01")
    ref_dtype = np.dtype({"names": ["Seq", "T0Ticks", "PeriodTicks"],
                          "formats": [byte_field(ref, n)[1] for n in ("Seq", "T0Ticks", "PeriodTicks")],
                          "offsets": [byte_field(ref, n)[0] for n in ("Seq", "T0Ticks", "PeriodTicks")], "itemsize": 8})
    classic = db.get_message_by_name("PressureClassic_C01")
    classic_dtype = _struct(classic, ["Seq"], [f"S{i}" for i in range(CLASSIC_SAMPLES)], 8)
    for table, proto in ((fd_id, fd), (ref_id, ref), (classic_id, classic)):  # every cylinder the same layout
        for fid in table:
            other = db.get_message_by_frame_id(fid)
            if [(s.start, s.length, s.is_signed, s.scale) for s in other.signals] != \
                    [(s.start, s.length, s.is_signed, s.scale) for s in proto.signals]:
                raise ValueError(f"{other.name} differs from {proto.name}")
    return Layouts(
        fd_dtype=fd_dtype, fd_period_factor=byte_field(fd, "PeriodTicks")[2], fd_scale_factor=byte_field(fd, "Scale")[2],
        fd_flag_bits={n: fd.get_signal_by_name(n).start - 8 * flags_byte
                      for n in (FLAG_SENSOR_FAULT, FLAG_DAQ_OVERRUN, FLAG_RESTART)},
        ref_dtype=ref_dtype, classic_dtype=classic_dtype, classic_factor=byte_field(classic, "S0")[2],
        fd_id=fd_id, ref_id=ref_id, classic_id=classic_id, cylinders=len(fd_id),
        load=db.get_message_by_name("GensetLoad"), results=db.get_message_by_name("FrictionResults"))


def _with_flags(dt: np.dtype, flags_byte: int) -> np.dtype:
    names = list(dt.names) + ["Flags"]
    return np.dtype({"names": names, "formats": [dt.fields[n][0] for n in dt.names] + ["u1"],
                     "offsets": [dt.fields[n][1] for n in dt.names] + [flags_byte], "itemsize": dt.itemsize})


# --- encoders ---------------------------------------------------------------------------------------------------
def pressure_counts(values_pa: np.ndarray, scale_pa: float | np.ndarray, saturated: np.ndarray | None) -> np.ndarray:
    """Pressure [Pa] -> int16 counts; NaN -> RAW_INVALID, out of range or ``saturated`` -> RAW_SATURATED."""
    v = np.asarray(values_pa, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        c = np.rint(v / scale_pa)
        over = ~(np.abs(c) <= RAW_SATURATED - 1)
    out = np.where(over, RAW_SATURATED, c)
    out[np.isnan(v)] = RAW_INVALID
    if saturated is not None:
        out[np.asarray(saturated, bool)] = RAW_SATURATED
    return out.astype(np.int16)


def fd_scale_for(values_pa: np.ndarray) -> float:
    """Smallest DBC-representable scale [Pa/count] that holds the largest finite |value| in 32766 counts."""
    lay = layouts()
    v = np.asarray(values_pa, dtype=np.float64)
    peak = float(np.max(np.abs(v[np.isfinite(v)]), initial=0.0))
    raw = min(0xFFFF, max(1, math.ceil(peak / (RAW_SATURATED - 1) / lay.fd_scale_factor - 1e-9)))
    return raw * lay.fd_scale_factor


def encode_pressure_fd(cylinder: int, seq: int, t0_ticks: int, period_ticks: float, values_pa: np.ndarray, *,
                       scale_pa: float | None = None, saturated: np.ndarray | None = None, sensor_fault: bool = False,
                       daq_overrun: bool = False, restart: bool = False) -> can.Message:
    """One CAN FD pressure frame of 1..25 samples (``values_pa`` Pa absolute; NaN -> invalid sample)."""
    lay = layouts()
    v = np.asarray(values_pa, dtype=np.float64).ravel()
    if not 1 <= v.size <= FD_SAMPLES:
        raise ValueError(f"a CAN FD pressure frame carries 1..{FD_SAMPLES} samples, got {v.size}")
    if not 0 < period_ticks < 65536:
        raise ValueError(f"period_ticks must be in (0, 65536), got {period_ticks}")
    scale = fd_scale_for(v) if scale_pa is None else float(scale_pa)
    rec = np.zeros(1, lay.fd_dtype)
    rec["Seq"] = seq & 0xFFFF
    rec["T0Ticks"] = int(t0_ticks) & 0xFFFFFFFF
    rec["PeriodTicks"] = round(period_ticks / lay.fd_period_factor)
    rec["Scale"] = round(scale / lay.fd_scale_factor)
    rec["NSamples"] = v.size
    bits = lay.fd_flag_bits
    rec["Flags"] = ((sensor_fault << bits[FLAG_SENSOR_FAULT]) | (daq_overrun << bits[FLAG_DAQ_OVERRUN])
                    | (restart << bits[FLAG_RESTART]))
    rec["samples"][0, :v.size] = pressure_counts(v, float(rec["Scale"][0]) * lay.fd_scale_factor, saturated)
    return can.Message(arbitration_id=lay.id_of("fd", cylinder), is_extended_id=False, is_fd=True,
                       bitrate_switch=True, data=rec.tobytes())


def encode_pressure_ref(cylinder: int, seq: int, t0_ticks: int, period_ticks: int) -> can.Message:
    """Classic-CAN time reference: data frame ``seq`` has its first sample at ``t0_ticks``."""
    if period_ticks != int(period_ticks) or not 1 <= period_ticks <= 0xFFFF:
        raise ValueError(f"classic CAN needs an integer sample period of 1..65535 ticks, got {period_ticks}")
    rec = np.zeros(1, layouts().ref_dtype)
    rec["Seq"], rec["T0Ticks"], rec["PeriodTicks"] = seq & 0xFFFF, int(t0_ticks) & 0xFFFFFFFF, int(period_ticks)
    return can.Message(arbitration_id=layouts().id_of("ref", cylinder), is_extended_id=False, data=rec.tobytes())


def encode_pressure_classic(cylinder: int, seq: int, values_pa: np.ndarray,
                            saturated: np.ndarray | None = None) -> can.Message:
    """Classic-CAN data frame of exactly 3 samples at the DBC's fixed scale."""
    lay = layouts()
    v = np.asarray(values_pa, dtype=np.float64).ravel()
    if v.size != CLASSIC_SAMPLES:
        raise ValueError(f"a classic pressure frame carries {CLASSIC_SAMPLES} samples, got {v.size}")
    rec = np.zeros(1, lay.classic_dtype)
    rec["Seq"] = seq & 0xFFFF
    rec["samples"][0] = pressure_counts(v, lay.classic_factor, saturated)
    return can.Message(arbitration_id=lay.id_of("classic", cylinder), is_extended_id=False, data=rec.tobytes())


def encode_load(power_w: float, torque_nm: float = math.nan, counter: int = 0,
                source_address: int = SA_GENSET) -> can.Message:
    """GensetLoad (J1939 PGN 0xFF10); NaN -> J1939 'not available' (all ones)."""
    msg = layouts().load
    raw = {"RealPower": j1939_raw(msg, "RealPower", power_w), "ShaftTorque": j1939_raw(msg, "ShaftTorque", torque_nm),
           "Counter": counter & 0xFF}
    data = msg.encode(raw, scaling=False, padding=True, strict=False)
    return can.Message(arbitration_id=j1939_id(PGN_LOAD, source_address), is_extended_id=True, data=data)


def j1939_not_available(length: int) -> int:
    return (1 << length) - 1


def j1939_max_valid(length: int) -> int:
    """Largest valid raw value of a J1939 parameter of ``length`` bits (above: reserved, error, not available).
    Whole bytes follow J1939-71 (top byte 0xFB.. reserved, 0xFE.. error, 0xFF.. not available); shorter fields
    keep only all-ones as 'not available'."""
    if length >= 8:
        return ((0xFA + 1) << (length - 8)) - 1
    return (1 << length) - 2


def j1939_status(raw: int, length: int) -> str | None:
    """None if ``raw`` is a valid value, else 'not_available', 'error' or 'reserved'."""
    if raw <= j1939_max_valid(length):
        return None
    top = raw >> (length - 8) if length >= 8 else 0xFF
    return {0xFF: "not_available", 0xFE: "error"}.get(top, "reserved")


def j1939_raw(msg: cantools.database.can.Message, name: str, value: float) -> int:
    """Raw J1939 value of ``value``: NaN -> 'not available', outside the signal's range -> 'error' indicator."""
    sig = msg.get_signal_by_name(name)
    if not math.isfinite(value):
        return j1939_not_available(sig.length)
    raw = round((value - sig.offset) / sig.scale)
    if not 0 <= raw <= j1939_max_valid(sig.length):
        return (0xFE << (sig.length - 8)) if sig.length >= 8 else j1939_not_available(sig.length)
    return raw


def j1939_value(msg: cantools.database.can.Message, name: str, raw: int) -> tuple[float, str | None]:
    """Physical value of a raw J1939 parameter, NaN with the reason if it is not a valid value."""
    sig = msg.get_signal_by_name(name)
    status = j1939_status(int(raw), sig.length)
    if status is not None:
        return math.nan, status
    return float(raw * sig.scale + sig.offset), None
