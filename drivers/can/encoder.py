"""The sending side of the pressure frames, as the DAQ firmware does it: blocks of samples -> CAN messages.

Used by the tests and by the simulator-to-bus bridge. CAN FD: 25 samples per frame, a per-frame scale chosen from
the frame's peak, T0 of each frame rounded to the tick. Classic CAN: 3 samples per frame at the DBC's fixed scale, a
time-reference frame before the first data frame and every ``ref_every`` data frames; samples that do not fill a
frame wait for the next block (or ``flush``).
"""

from __future__ import annotations

import math

import can
import numpy as np
from frictionwatch.drivers.can.codec import (
    CLASSIC_SAMPLES,
    FD_SAMPLES,
    FLAG_RESTART,
    RAW_SATURATED,
    encode_pressure_classic,
    encode_pressure_ref,
    layouts,
    pressure_counts,
)


class PressureEncoder:
    """Per-cylinder counters and framing; ``block(...)`` returns the messages to send, in order."""

    def __init__(self, fd: bool = True, ref_every: int = 32) -> None:
        if not 1 <= ref_every <= 1024:
            raise ValueError("ref_every must be 1..1024 data frames")
        self.fd = fd
        self.ref_every = ref_every
        self.seq: dict[int, int] = {}
        self._since_ref: dict[int, int] = {}
        self._restart: set[int] = set()
        self._carry: dict[int, tuple[int, float, np.ndarray, np.ndarray]] = {}  # classic: t0, period, values, sat

    def restart(self) -> None:
        """Behave as after a DAQ reset: counters from 0, RESTART flag on the next CAN FD frame of each cylinder."""
        self._restart = set(self.seq) | self._restart
        self.seq.clear()
        self._since_ref.clear()
        self._carry.clear()

    def block(self, cylinder: int, t0_ticks: int, period_ticks: float, values_pa: np.ndarray,
              saturated: np.ndarray | None = None) -> list[can.Message]:
        """Frames for ``values_pa`` [Pa abs] sampled at ``t0_ticks + i * period_ticks`` (NaN -> invalid sample)."""
        v = np.asarray(values_pa, dtype=np.float64).ravel()
        sat = np.zeros(v.size, bool) if saturated is None else np.asarray(saturated, bool).ravel()
        if sat.size != v.size:
            raise ValueError("saturated must have the shape of values_pa")
        if v.size == 0:
            return []
        if self.fd:
            return self._fd(cylinder, int(t0_ticks), float(period_ticks), v, sat)
        return self._classic(cylinder, int(t0_ticks), float(period_ticks), v, sat)

    def flush(self, cylinder: int) -> list[can.Message]:
        """Classic: send held samples, padding the frame with invalid samples."""
        if cylinder not in self._carry:
            return []
        t0, period, v, sat = self._carry.pop(cylinder)
        pad = CLASSIC_SAMPLES - v.size
        return self._classic_frames(cylinder, t0, period, np.concatenate([v, np.full(pad, np.nan)]),
                                    np.concatenate([sat, np.zeros(pad, bool)]))

    def _next_seq(self, cylinder: int, k: int) -> int:
        s = self.seq.get(cylinder, 0)
        self.seq[cylinder] = (s + k) & 0xFFFF
        return s

    def _fd(self, cyl: int, t0: int, period: float, v: np.ndarray, sat: np.ndarray) -> list[can.Message]:
        lay = layouts()
        if not 0 < period < 65536:
            raise ValueError(f"period_ticks must be in (0, 65536), got {period}")
        k = math.ceil(v.size / FD_SAMPLES)
        padded = np.full(k * FD_SAMPLES, np.nan)
        padded[:v.size] = v
        rows = padded.reshape(k, FD_SAMPLES)
        sat_rows = np.zeros(k * FD_SAMPLES, bool)
        sat_rows[:v.size] = sat
        peak = np.nanmax(np.where(np.isfinite(rows), np.abs(rows), 0.0), axis=1)
        scale_raw = np.clip(np.ceil(peak / (RAW_SATURATED - 1) / lay.fd_scale_factor - 1e-9), 1, 0xFFFF)
        rec = np.zeros(k, lay.fd_dtype)
        first = self._next_seq(cyl, k)
        rec["Seq"] = (first + np.arange(k)) & 0xFFFF
        rec["T0Ticks"] = np.rint(t0 + np.arange(k) * FD_SAMPLES * period).astype(np.int64) & 0xFFFFFFFF
        rec["PeriodTicks"] = round(period / lay.fd_period_factor)
        rec["Scale"] = scale_raw
        n = np.full(k, FD_SAMPLES)
        n[-1] = v.size - (k - 1) * FD_SAMPLES
        rec["NSamples"] = n
        if cyl in self._restart:
            self._restart.discard(cyl)
            rec["Flags"][0] |= 1 << lay.fd_flag_bits[FLAG_RESTART]
        counts = pressure_counts(rows, (scale_raw * lay.fd_scale_factor)[:, None], sat_rows.reshape(k, FD_SAMPLES))
        counts[np.arange(FD_SAMPLES) >= n[:, None]] = 0
        rec["samples"] = counts
        blob = rec.tobytes()
        fid = lay.id_of("fd", cyl)
        return [can.Message(arbitration_id=fid, is_extended_id=False, is_fd=True, bitrate_switch=True,
                            data=blob[64 * i:64 * (i + 1)]) for i in range(k)]

    def _classic(self, cyl: int, t0: int, period: float, v: np.ndarray, sat: np.ndarray) -> list[can.Message]:
        out: list[can.Message] = []
        if cyl in self._carry:
            c_t0, c_period, c_v, c_sat = self._carry[cyl]
            if c_period == period and abs(c_t0 + c_v.size * period - t0) <= 1:
                del self._carry[cyl]
                t0, v, sat = c_t0, np.concatenate([c_v, v]), np.concatenate([c_sat, sat])
            else:
                out += self.flush(cyl)
        whole = v.size - v.size % CLASSIC_SAMPLES
        if whole < v.size:
            self._carry[cyl] = (round(t0 + whole * period), period, v[whole:], sat[whole:])
        return out + self._classic_frames(cyl, t0, period, v[:whole], sat[:whole])

    def _classic_frames(self, cyl: int, t0: int, period: float, v: np.ndarray, sat: np.ndarray) -> list[can.Message]:
        if period != round(period):
            raise ValueError(f"classic CAN needs an integer sample period in ticks, got {period}")
        out: list[can.Message] = []
        for i in range(v.size // CLASSIC_SAMPLES):
            seq = self._next_seq(cyl, 1)
            t_frame = round(t0 + i * CLASSIC_SAMPLES * period)
            since = self._since_ref.get(cyl)
            if since is None or since >= self.ref_every:
                out.append(encode_pressure_ref(cyl, seq, t_frame, int(period)))
                since = 0
            self._since_ref[cyl] = since + 1
            s = slice(i * CLASSIC_SAMPLES, (i + 1) * CLASSIC_SAMPLES)
            out.append(encode_pressure_classic(cyl, seq, v[s], sat[s]))
        return out
