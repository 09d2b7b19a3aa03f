"""drivers/daq/raw.py, teeth.py, pressure.py on synthetic signals with known truth.

The synthetic wheel imitates the TU/e signal (README of tue-4gb10-si-encoder-pressure): low rail -0.75 V, pulses to
+3.5 V, and a weak first tooth after the 60-2 gap (a bump that may stay below 0 V). Flanks are linear and slow enough
(timing level >= 1 sample above the rail) that the linearly interpolated crossing is exact: edge times are checked to
the tick. (The real flanks take 2-3 samples, where interpolation errs by up to ~0.1 sample.)
"""

from __future__ import annotations

import gzip
from collections import Counter

import numpy as np
import pytest
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.kinematics import cylinder_volume as core_volume
from frictionwatch.core.types import AcquisitionInfo, PressureBlock, ToothBatch
from frictionwatch.drivers.daq.pressure import (
    calibrate_cycles,
    cylinder_volume,
    firing_turns,
    wheel_angle_of_samples,
)
from frictionwatch.drivers.daq.raw import daq_to_records, process_daq, read_daq_table
from frictionwatch.drivers.daq.teeth import detect_teeth, hysteresis_edges, sync_wheel
from frictionwatch.drivers.errors import CorruptLog
from numpy.testing import assert_allclose

FS = 100e3  # sample rate [Hz]
LOW, HIGH = -0.75, 3.5
SLOPE = 0.6  # V per sample: 0 V lies 1.25 samples up the flank
ENGINE = load_engine("tue-4gb10")


def wheel_signal(n_rev=6, rpm=3000.0, weak_peak=-0.2, drop=(), extra=(), noise=0.0, seed=0, t_first=0.002):
    """Synthetic 60-2 signal: revolutions 0..n_rev-1 plus the closing tooth 0 of revolution n_rev.
    Returns (volts, edge_pos [samples], tooth_index, weak mask).

    drop: (rev, tooth) pairs left out; extra: sample positions of spurious full pulses. Tooth 0 (first after the
    gap) is a flat-topped bump of height weak_peak - LOW, timed at half height when that is below 0 V.
    """
    rng = np.random.default_rng(seed)
    pitch = FS / rpm  # samples per tooth pitch (60 pitches per revolution)
    n = int(t_first * FS + (n_rev + 1) * 60 * pitch)
    x = np.full(n, LOW)
    i = np.arange(n, dtype=np.float64)
    pos, tooth, weak = [], [], []
    for r in range(n_rev + 1):
        for j in range(58 if r < n_rev else 1):
            t = t_first * FS + (r * 60 + j) * pitch
            if (r, j) in drop:
                continue
            if j == 0:
                h = weak_peak - LOW
                slope = h / 4.0  # rises over 4 samples, so half height is 2 samples up the flank
                t0 = t - 2.0  # half height at t
                up = LOW + slope * (i - t0)
                down = weak_peak - slope * (i - (t0 + 6.0))  # 2-sample plateau: the sampled peak is exact
                x = np.maximum(x, np.clip(np.minimum(up, down), LOW, weak_peak))
                is_weak = 0.5 * (weak_peak + LOW) < 0.0
                if not is_weak:  # strong bump: timed at 0 V
                    t = t0 + (0.0 - LOW) / slope
                pos.append(t), tooth.append(j), weak.append(is_weak)
                continue
            x = np.maximum(x, _pulse(i, t, 0.45 * pitch))
            pos.append(t), tooth.append(j), weak.append(False)
    for t in extra:  # a 3-sample spike through 0 V at t (EMI-like)
        x = np.maximum(x, np.clip(2.0 - 2.0 * np.abs(i - (t + 1.0)), LOW, HIGH))
    x += noise * rng.standard_normal(n)
    return x, np.array(pos), np.array(tooth), np.array(weak)


def _pulse(i, t, width):
    """Trapezoid crossing 0 V upward at sample position t."""
    start = t - (0.0 - LOW) / SLOPE
    up = LOW + SLOPE * (i - start)
    down = HIGH - SLOPE * (i - (start + width))
    return np.clip(np.minimum(up, down), LOW, HIGH)


# ---- edge kernel ----------------------------------------------------------------------------------------------


def reference_edges(w, arm, fire, level, frac):
    """Plain-Python statement of the detector in drivers/daq/teeth.py's docstring."""
    out, state, vmin, imin = [], "wait", None, 0
    i = 0
    while i < len(w):
        if state == "wait":
            state = "armed" if w[i] < arm else "wait"
            vmin, imin = w[i], i
        elif state == "armed":
            if w[i] < vmin:
                vmin, imin = w[i], i
            if w[i] > fire:
                end = i
                while end < len(w) and w[end] >= arm:
                    end += 1
                if end == len(w):
                    break
                ipk = i + int(np.argmax(w[i:end]))
                lev = min(level, vmin + frac * (w[ipk] - vmin))
                j = next(k for k in range(imin + 1, ipk + 1) if w[k] >= lev or k == ipk)
                out.append((j - 1 + (lev - w[j - 1]) / (w[j] - w[j - 1]), w[ipk]))
                i, vmin, imin = end, w[end], end
        i += 1
    return np.array(out).reshape(-1, 2)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_kernel_matches_reference(seed):
    rng = np.random.default_rng(seed)
    w = np.cumsum(rng.standard_normal(4000)) * 0.3  # random walk: many odd pulses, plateaus, weak bumps
    w = np.clip(w - w.mean(), -0.8, 4.0)
    pos, peak, _ = hysteresis_edges(w, -0.5, -0.3, 0.0, 0.5)
    ref = reference_edges(w, -0.5, -0.3, 0.0, 0.5)
    assert pos.shape[0] == ref.shape[0] > 5
    assert_allclose(pos, ref[:, 0], atol=1e-12)
    assert_allclose(peak, ref[:, 1], atol=0)


def test_kernel_rejects_bad_thresholds():
    with pytest.raises(ValueError, match="arm"):
        hysteresis_edges(np.zeros(10), 0.5, 0.2)
    with pytest.raises(ValueError, match="NaN"):
        hysteresis_edges(np.array([0.0, np.nan, 1.0]), -0.5, 0.2)


# ---- tooth detection and sync ---------------------------------------------------------------------------------


@pytest.mark.parametrize("weak_peak", [-0.3, 0.1, 1.5])
def test_edges_exact_and_weak_first_tooth_found(weak_peak):
    w, pos, tooth, weak = wheel_signal(weak_peak=weak_peak)
    e = detect_teeth(w, FS, tick_hz=10e6)
    assert e.ticks.shape == pos.shape
    assert_allclose(e.ticks, np.rint(pos * 100), atol=1)  # 100 ticks per sample; exact up to rounding
    assert e.revs_ok == 5 and not e.damage  # 6 gaps -> 5 revolutions between them
    synced = e.tooth_index >= 0
    assert_allclose(e.tooth_index[synced], tooth[synced])
    assert np.array_equal(e.weak, weak)
    assert_allclose(e.rev_speed_rpm(), 3000.0, rtol=1e-5)


def test_naive_zero_threshold_misses_the_weak_tooth_ours_does_not():
    w, pos, _, _ = wheel_signal(weak_peak=-0.2, noise=0.02)
    s = w > 0.0
    naive = np.count_nonzero(s[1:] & ~s[:-1])
    e = detect_teeth(w, FS)
    assert naive == pos.shape[0] - 7  # the seven weak teeth (tooth 0 of revolutions 0..6) never cross 0 V
    assert e.ticks.shape[0] == pos.shape[0] and e.revs_ok == 5


def test_noise_makes_no_spurious_edges():
    # 20 mV rms floor noise (the TU/e floor has 21 mV std and at most 70 mV sample-to-sample)
    w, pos, _, weak = wheel_signal(noise=0.02, seed=3)
    e = detect_teeth(w, FS)
    assert e.ticks.shape == pos.shape and e.revs_ok == 5 and not e.damage
    err = np.abs(e.ticks - pos * 100)  # ticks (100 per sample)
    assert err[~weak].max() < 12  # 0.02 V / 0.6 V per sample, both samples noisy: < 0.12 sample
    assert err[weak].max() < 60  # weak bump: 0.14 V/sample and a level set by the noisy floor and peak


def test_dropped_tooth_skips_that_revolution_and_resyncs():
    w, _, _, _ = wheel_signal(n_rev=7, drop={(2, 30)})
    e = detect_teeth(w, FS)
    assert e.revs_ok == 5
    assert sum(e.damage.values()) == 1
    assert set(e.damage) <= {"teeth_per_rev_57", "dropped_or_spurious_tooth"}
    # revolution r of the generator is turn r - 1 (turn 0 starts at the first gap); turn 1 is skipped, and the
    # turn numbers keep counting through it, so the 4-stroke parity survives
    assert e.rev_turn.tolist() == [0, 2, 3, 4, 5]


def test_spurious_pulse_skips_that_revolution():
    pitch = FS / 1500.0
    w, _, _, _ = wheel_signal(n_rev=7, rpm=1500.0, extra=[0.002 * FS + (3 * 60 + 20.75) * pitch])
    e = detect_teeth(w, FS)
    assert e.revs_ok == 5 and e.damage == Counter({"teeth_per_rev_59": 1})


def test_sync_dropout_breaks_turn_count():
    pitch = 100 * FS / 3000.0  # ticks per tooth at 3000 rpm, 100 ticks per sample
    one = [r * 60 * pitch + j * pitch for r in range(4) for j in range(58)]
    ticks = np.array(one + [t + 10 * 60 * pitch for t in one], dtype=np.int64)  # 6 revolutions lost in between
    _, _, turns, damage = sync_wheel(ticks, 60, 2)
    # gaps open revolutions 1, 2, 3 and 11, 12, 13; revolution 3 runs into the dropout and is lost
    assert damage == Counter({"signal_dropout": 1})
    assert turns.shape[0] == 4 and turns[1] - turns[0] == 1 and turns[2] - turns[1] >= 1000


def test_flat_signal_is_a_clear_error():
    with pytest.raises(ValueError, match="flat"):
        detect_teeth(np.zeros(1000), FS)


# ---- pressure: volume, phase, calibration ---------------------------------------------------------------------


def test_volume_matches_core_kinematics():
    th = np.linspace(-360, 360, 97)
    ref = core_volume(np.radians(th), ENGINE.kinematics_params(), ENGINE.piston_area, ENGINE.clearance_volume)
    assert_allclose(cylinder_volume(th, ENGINE), ref, rtol=1e-12)


def motored_volts(theta_deg, gain, zero, p_bdc=1.0e5, n=1.32):
    """Ideal motored pressure (polytropic from intake BDC, physics.md §14.6) as sensor volts."""
    th = np.mod(theta_deg + 360.0, 720.0) - 360.0  # -360..360 around firing TDC
    v = cylinder_volume(th, ENGINE)
    v_bdc = cylinder_volume(np.array([180.0]), ENGINE)[0]
    p = np.where(np.abs(th) < 180.0, p_bdc * (v_bdc / v) ** n, p_bdc)
    return zero + p / gain


def test_phase_and_calibration_recover_gain_and_zero():
    w, _, _, _ = wheel_signal(n_rev=8, weak_peak=1.0)
    e = detect_teeth(w, FS)
    ticks = np.arange(w.shape[0], dtype=np.int64) * 100
    phi = wheel_angle_of_samples(ticks, e.ticks, e.rev_start, e.rev_end, e.rev_turn, 60, 2)
    tdc = 244.5
    gain, zero = 12.4e5, 1.7  # Pa/V, V
    ok = np.isfinite(phi)
    volts = np.full(w.shape[0], zero + 1.0e5 / gain)
    volts[ok] = motored_volts(phi[ok] - (360.0 + tdc), gain, zero)  # firing TDC in odd turns
    fire, dmg = firing_turns(phi, volts, e.rev_turn, tdc)
    assert not dmg and fire.tolist() == [t for t in e.rev_turn.tolist() if t % 2 == 1]
    cals, dmg = calibrate_cycles(phi, volts, 360.0 * fire + tdc, ENGINE, n_poly=1.32, peg_pa=1.0e5)
    assert not dmg and len(cals) == fire.shape[0]
    assert_allclose([c.zero_v for c in cals], zero, atol=1e-6)
    # the +-5 deg BDC window averages p slightly above p(BDC) (V is 0.1 % below V_BDC at 175 deg): 1e-3
    assert_allclose([c.gain_pa_per_v for c in cals], gain, rtol=1e-3)
    # given gain + bdc pegging gives the same zero
    cals_b, _ = calibrate_cycles(phi, volts, 360.0 * fire + tdc, ENGINE, peg="bdc", gain_pa_per_v=gain)
    assert_allclose([c.zero_v for c in cals_b], zero, atol=1e-4)


def test_polytropic_zero_does_not_need_manifold_pressure():
    # throttled engine: p(BDC) = 0.4 bar; with the gain known, polytropic pegging still finds the zero, BDC pegging
    # at 1 bar would be 0.6 bar off (why process_daq defaults to peg="polytropic")
    w, _, _, _ = wheel_signal(n_rev=6, weak_peak=1.0)
    e = detect_teeth(w, FS)
    ticks = np.arange(w.shape[0], dtype=np.int64) * 100
    phi = wheel_angle_of_samples(ticks, e.ticks, e.rev_start, e.rev_end, e.rev_turn, 60, 2)
    ok = np.isfinite(phi)
    volts = np.full(w.shape[0], 2.0)
    volts[ok] = motored_volts(phi[ok] - 244.5, 12.4e5, 2.0, p_bdc=0.4e5)
    fire, _ = firing_turns(phi, volts, e.rev_turn, 244.5)
    cals, _ = calibrate_cycles(phi, volts, 360.0 * fire + 244.5, ENGINE, gain_pa_per_v=12.4e5)
    assert_allclose([c.zero_v for c in cals], 2.0, atol=1e-6)
    assert_allclose([c.implied_gain_pa_per_v for c in cals], 12.4e5 / 0.4, rtol=1e-3)


def test_wrong_tdc_is_skipped_not_silently_wrong():
    w, _, _, _ = wheel_signal(n_rev=6, weak_peak=1.0)
    e = detect_teeth(w, FS)
    ticks = np.arange(w.shape[0], dtype=np.int64) * 100
    phi = wheel_angle_of_samples(ticks, e.ticks, e.rev_start, e.rev_end, e.rev_turn, 60, 2)
    ok = np.isfinite(phi)
    volts = np.full(w.shape[0], 2.0)
    volts[ok] = motored_volts(phi[ok] - 244.5, 12.4e5, 2.0)
    fire, _ = firing_turns(phi, volts, e.rev_turn, 100.0)  # TDC given 144 deg early
    cals, dmg = calibrate_cycles(phi, volts, 360.0 * fire + 100.0, ENGINE)
    assert not cals and sum(dmg.values()) >= 2


# ---- file reading and records ----------------------------------------------------------------------------------


def write_table(path, wheel, pressure, swap=False, gz=True):
    t = np.arange(wheel.shape[0]) / FS
    cols = (t, pressure, wheel) if swap else (t, wheel, pressure)
    text = "\n".join("\t".join(f"{v:.6E}" for v in row) for row in zip(*cols, strict=True)) + "\n"
    (gzip.open if gz else open)(path, "wt").write(text)


@pytest.fixture(scope="module")
def synthetic_file(tmp_path_factory):
    w, pos, _, _ = wheel_signal(n_rev=9, weak_peak=0.0, noise=0.01, seed=5)
    e = detect_teeth(w, FS)
    ticks = np.arange(w.shape[0], dtype=np.int64) * 100
    phi = wheel_angle_of_samples(ticks, e.ticks, e.rev_start, e.rev_end, e.rev_turn, 60, 2)
    ok = np.isfinite(phi)
    volts = np.full(w.shape[0], 1.5 + 1.0e5 / 12.4e5)
    volts[ok] = motored_volts(phi[ok] - 244.5, 12.4e5, 1.5)
    path = tmp_path_factory.mktemp("daq") / "trainingset_synthetic.txt.gz"
    write_table(path, w, volts, swap=True)  # pressure first, as in the trainingset_* files
    return path, pos, volts


def test_read_finds_columns_by_content(synthetic_file):
    path, _, volts = synthetic_file
    tr = read_daq_table(path)
    assert tr.columns == (3, 2) and tr.sample_rate_hz == pytest.approx(FS)
    assert_allclose(tr.pressure_v, volts, atol=1e-6)


def test_records_like_a_live_source(synthetic_file):
    path, pos, _ = synthetic_file
    info, recs = daq_to_records(path, "60-2", 244.5, gain_pa_per_v=12.4e5, block_s=0.005)
    assert isinstance(info, AcquisitionInfo)
    assert (info.tick_hz, info.wheel_teeth, info.wheel_missing, info.first_tooth_deg) == (10e6, 60, 2, -244.5)
    assert info.cam_deg is None and info.pressure_cylinders == (1,)
    teeth = np.concatenate([r.ticks for r in recs if isinstance(r, ToothBatch)])
    assert teeth.dtype == np.int64 and np.all(np.diff(teeth) > 0)
    assert_allclose(teeth, pos * 100, atol=25)  # 10 mV noise on 0.6 V/sample flanks (weak bumps: 0.19 V/sample)
    blocks = [r for r in recs if isinstance(r, PressureBlock)]
    starts = np.array([b.t0_ticks for b in blocks])
    sizes = np.array([b.values.shape[0] for b in blocks])
    assert_allclose(starts[1:], starts[:-1] + sizes[:-1] * 100)  # contiguous, no overlap
    # acquisition order: each ToothBatch is followed by the PressureBlock of the same time window
    for i, r in enumerate(recs):
        if isinstance(r, ToothBatch):
            b = recs[i + 1]
            assert isinstance(b, PressureBlock)
            assert b.t0_ticks <= r.ticks[0] and r.ticks[-1] < b.t0_ticks + b.values.shape[0] * b.period_ticks
    p = np.concatenate([b.values for b in blocks])
    fin = p[np.isfinite(p)]
    assert fin.size > 0.7 * p.size and 0.9e5 < fin.min() and fin.max() < 20e5


def test_process_daq_cycles(synthetic_file):
    path, _, _ = synthetic_file
    res = process_daq(read_daq_table(path), gain_pa_per_v=12.4e5)
    ks = res.complete_cycles()
    assert len(ks) == 3 and not res.damage  # 9 revolutions between 10 gaps -> TDC-centred cycles in turns 2,4,6
    grid = np.arange(-360.0, 360.0, 1.0)
    p = res.cycle_on_grid(ks[0], grid)
    v = cylinder_volume(grid, ENGINE)
    v_bdc = cylinder_volume(np.array([180.0]), ENGINE)[0]
    ideal = np.where(np.abs(grid) < 180.0, 1.0e5 * (v_bdc / v) ** 1.32, 1.0e5)
    assert_allclose(p, ideal, rtol=0.01, atol=2e3)  # 10 mV noise on the wheel moves angles by < 0.01 deg


def test_corrupt_and_odd_tables(tmp_path):
    bad = tmp_path / "bad.txt"
    bad.write_text("0 1 2\n1 x 3\n")
    with pytest.raises(CorruptLog):
        read_daq_table(bad)
    short = tmp_path / "short.txt"
    short.write_text("0 1\n" * 200)
    with pytest.raises(CorruptLog, match="3 columns"):
        read_daq_table(short)
    jumpy = tmp_path / "jumpy.txt"
    t = np.arange(300) * 1e-5
    t[150:] += 1e-3
    np.savetxt(jumpy, np.column_stack([t, np.sin(t * 1e4), np.cos(t)]))
    with pytest.raises(CorruptLog, match="uniformly"):
        read_daq_table(jumpy)
    with pytest.raises(FileNotFoundError):
        read_daq_table(tmp_path / "absent.txt.gz")
    with pytest.raises(ValueError, match="wheel"):
        daq_to_records(jumpy, wheel="sixty")
