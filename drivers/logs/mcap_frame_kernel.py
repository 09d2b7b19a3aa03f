"""A ``PressureFrame`` message's protobuf bytes decoded in one compiled pass, and a tooth / cam batch's ticks
(design note 94).

A genset-v20 frame (20 cylinders x 200 samples as ADC counts, ~8.8 kB) is most of a replay's decoding: upb's
``FromString`` (~20 us) then ``np.array`` over its repeated field of 4,000 Python ints (~11 us) and the checks (~5 us),
~37 us a frame and 8 frames a cycle. ``frame_counts_kernel`` reads the wire bytes straight into the (k, n) float64
values, each ``float64(count) * scale_pa[row]`` -- the product the reference (mcap_schema ``_decode_frame``) forms.

It takes the message only as our writer makes it (upb's canonical encoding: every field at most once, repeated
fields packed, no field we do not know, 32-bit fields in 32 bits) and only the counts form (``values_pa`` absent),
and only when every check of the reference passes; anything else it declines (``DECLINED``) and ``decode_frame``
hands the bytes to the reference, which decodes or raises exactly as before. So a message decodes to the same
record, or fails with the same error, either way (tests/drivers/test_mcap_frame_kernel.py: every frame of the replay
logs, and crafted ones of each declined kind). The same for a tooth or cam batch (~40 ticks: upb parses them in
~0.7 us, ``np.array`` over its repeated field then takes ~5): ``ticks_kernel``.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numba
import numpy as np
from frictionwatch.core.types import PressureFrame

DECLINED = 1  # the kernel's status when the reference must decode the message (module doc)
_WIRE = np.array([0, 2, 0, 1, 0, 2, 2, 2, 2], np.int64)  # field number -> wire type in the canonical encoding
_U32 = 0xFFFFFFFF


@numba.njit(cache=True)
def _varint(buf, pos, end):
    """(value, position after it) of the base-128 varint at ``pos``, its 64 bits as an int64 (a negative int64's two's
    complement, as protobuf writes it); position -1 if it runs past ``end`` or past 10 bytes (the reference raises)."""
    value = np.int64(0)
    for i in range(10):
        if pos + i >= end:
            return value, -1
        b = np.int64(buf[pos + i])
        value |= (b & 0x7F) << (7 * i)  # the 10th byte's bits past 64 drop, as protobuf's decoders drop them
        if b < 0x80:
            return value, pos + i + 1
    return value, -1


@numba.njit(cache=True)
def _uint32s(buf, lo, hi, out):
    """The packed uint32 varints of buf[lo:hi] into ``out``; how many, -1 if more than ``out`` holds, one is
    malformed or above 32 bits."""
    n = 0
    p = lo
    while p < hi:
        v, p = _varint(buf, p, hi)
        if p < 0 or v < 0 or v > _U32 or n >= out.size:
            return -1
        out[n] = v
        n += 1
    return n


@numba.njit(cache=True)
def _scaled_counts(buf, lo, hi, scale, flat, n):
    """The packed sint32 counts of buf[lo:hi], row r of ``n`` samples times ``scale[r]``, into ``flat`` (k * n);
    False unless there are exactly k * n, each a varint of at most 5 bytes within 32 bits (the canonical encoding)."""
    p = lo
    for r in range(scale.size):
        s = scale[r]
        for i in range(n):
            v = np.int64(0)
            shift = 0
            while True:
                if p >= hi or shift > 28:
                    return False
                b = np.int64(buf[p])
                p += 1
                v |= (b & 0x7F) << shift
                if b < 0x80:
                    break
                shift += 7
            if v > _U32:
                return False
            flat[r * n + i] = np.float64((v >> 1) ^ -(v & 1)) * s  # zigzag: sint32's count, then the reference's product
    return p == hi


@numba.njit(cache=True)
def frame_counts_kernel(buf, wire):
    """``(status, cylinders, t0_ticks, period_ticks, values)`` of a PressureFrame's bytes ``buf`` (uint8);
    status 0: decoded, DECLINED: the reference decides (module doc). ``wire``: ``_WIRE``."""
    no_c = np.zeros(0, np.int64)
    no_v = np.zeros((0, 0), np.float64)
    lo = np.full(9, -1, np.int64)
    hi = np.full(9, -1, np.int64)
    t0 = np.int64(0)
    samples = np.int64(0)
    period = 0.0
    end = buf.size
    pos = 0
    while pos < end:
        tag, pos = _varint(buf, pos, end)
        if pos < 0 or tag < 8 or tag > 8 * 8 + 7:
            return DECLINED, no_c, t0, period, no_v
        f = tag >> 3
        wt = tag & 7
        if wt != wire[f] or lo[f] >= 0:  # not canonical, or a field twice
            return DECLINED, no_c, t0, period, no_v
        if wt == 0:
            v, nxt = _varint(buf, pos, end)
            if nxt < 0 or (f == 4 and (v < 0 or v > _U32)):
                return DECLINED, no_c, t0, period, no_v
            if f == 2:
                t0 = v
            else:
                samples = v
            lo[f], hi[f] = pos, nxt
            pos = nxt
        elif wt == 1:
            if pos + 8 > end:
                return DECLINED, no_c, t0, period, no_v
            period = buf[pos:pos + 8].view(np.float64)[0]
            lo[f], hi[f] = pos, pos + 8
            pos += 8
        else:
            length, start = _varint(buf, pos, end)
            if start < 0 or length < 0 or length > end - start:
                return DECLINED, no_c, t0, period, no_v
            lo[f], hi[f] = start, start + length
            pos = start + length
    k_max = hi[1] - lo[1]  # at least a byte a cylinder
    n = samples
    if lo[5] >= 0 or k_max <= 0 or n == 0 or lo[7] < 0 or not (period > 0.0 and math.isfinite(period)):
        return DECLINED, no_c, t0, period, no_v  # values_pa form, no cylinders, no samples...: the reference
    cylinders = np.empty(k_max, np.int64)
    k = _uint32s(buf, lo[1], hi[1], cylinders)
    if k <= 0 or hi[6] - lo[6] != 8 * k:
        return DECLINED, no_c, t0, period, no_v
    cylinders = cylinders[:k]
    for r in range(k):
        if cylinders[r] < 1:
            return DECLINED, no_c, t0, period, no_v
        for q in range(r):
            if cylinders[q] == cylinders[r]:
                return DECLINED, no_c, t0, period, no_v
    scale = buf[lo[6]:hi[6]].view(np.float64)
    for r in range(k):
        if not (scale[r] > 0.0 and math.isfinite(scale[r])):
            return DECLINED, no_c, t0, period, no_v
    values = np.empty((k, n), np.float64)
    flat = values.reshape(k * n)
    if not _scaled_counts(buf, lo[7], hi[7], scale, flat, n):
        return DECLINED, no_c, t0, period, no_v
    if lo[8] >= 0:
        invalid = np.empty(hi[8] - lo[8], np.int64)
        m = _uint32s(buf, lo[8], hi[8], invalid)
        if m <= 0:
            return DECLINED, no_c, t0, period, no_v
        for j in range(m):
            if invalid[j] >= k * n:
                return DECLINED, no_c, t0, period, no_v
            flat[invalid[j]] = np.nan
    return 0, cylinders, t0, period, values


@numba.njit(cache=True)
def ticks_kernel(buf):
    """``(status, ticks)`` of a tooth / cam batch's bytes ``buf`` (uint8): the packed int64 field 1 as the only
    field; status DECLINED for anything else (the reference decides, module doc)."""
    none = np.zeros(0, np.int64)
    end = buf.size
    tag, pos = _varint(buf, 0, end)
    if pos < 0 or tag != (1 << 3 | 2):
        return DECLINED, none
    length, start = _varint(buf, pos, end)
    if start < 0 or length != end - start:
        return DECLINED, none
    out = np.empty(length, np.int64)  # a varint is at least a byte
    n = 0
    p = start
    while p < end:
        v, p = _varint(buf, p, end)
        if p < 0:
            return DECLINED, none
        out[n] = v
        n += 1
    return 0, out[:n].copy()


def frame_counts(data: bytes) -> tuple[int, np.ndarray, int, float, np.ndarray]:
    """``frame_counts_kernel`` of the message bytes ``data``."""
    return frame_counts_kernel(np.frombuffer(data, np.uint8), _WIRE)


def decode_ticks(data: bytes, reference: Callable[[bytes], np.ndarray]) -> np.ndarray:
    """The int64 ticks of a tooth / cam batch's protobuf ``data``: by ``ticks_kernel``, or by ``reference`` where
    it declines (module doc)."""
    status, ticks = ticks_kernel(np.frombuffer(data, np.uint8))
    return reference(data) if status else ticks


def decode_frame(data: bytes, reference: Callable[[bytes], PressureFrame]) -> PressureFrame:
    """The frame of protobuf ``data``: by the kernel, or by ``reference`` (mcap_schema ``_decode_frame``) where the
    kernel declines (module doc)."""
    status, cylinders, t0, period, values = frame_counts(data)
    if status:
        return reference(data)
    return PressureFrame(tuple(cylinders.tolist()), int(t0), float(period), values)
