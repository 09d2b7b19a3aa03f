"""The pressure-trace plausibility check (core.monitor.checks.pressure_trace, design note 144): a channel that is no
cylinder's pressure is flagged on its cylinder with its kind and kept out of the figures; a healthy one, or one off
only in calibration (pegging within +-10 bar, gain, TDC), is not flagged. Thresholds were tuned on seed 3
(bench/pressure_lies.py); these runs use seeds 5 and 7."""

from collections import Counter

import numpy as np
import pytest
from frictionwatch.core.model.effects.catalog import PressureGain, PressureOffset, TdcOffset
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.monitor.checks.pressure_trace import (
    KINDS,
    PressureTraceConfig,
    PressureTraceState,
    check_traces,
    failures,
    trace_features,
    trace_features_reference,
    trace_verdict_kernel,
)
from frictionwatch.core.monitor.pipeline import STAGES, CyclePipeline, PressureTrace
from frictionwatch.core.monitor.report.run_summary import end_of_run_status
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.service.pipeline import assembled_cycles
from numpy.testing import assert_allclose, assert_array_equal

from bench.pressure_lies import POINTS, lie

CFG = PressureTraceConfig()


def cycles_of(name, point, seed, n, fault="healthy", cyl=1, effects=None):
    spec = load_engine(name)
    rpm, load = POINTS[name][point]
    sim = simulate(spec, rpm, load, n, seed=seed, effects=effects)
    cyc, _ = assembled_cycles(spec, sim.info, lie(sim.records, fault, cyl, sim.info.tick_hz, rpm, seed))
    return spec, cyc


def flags_over(spec, cycles):
    state, out = PressureTraceState.empty(spec.n_cyl), []
    for c in cycles:
        state, _, flags, refused = check_traces(CFG, state, c.pressure, c.grid, spec.firing_angles)
        out.append((flags, refused))
    return out


@pytest.fixture(scope="module")
def maruti():
    return cycles_of("maruti-3cyl", 0, 5, 8)


def test_kernel_equals_the_numpy_reference(maruti):
    spec, cyc = maruti
    rng = np.random.default_rng(0)
    for c in cyc[:3]:
        p = c.pressure.copy()
        cases = [p, -p, np.zeros_like(p), np.minimum(p, 0.6 * p.max()), p + rng.normal(0, 1e3, p.shape)]
        gappy = p.copy()
        gappy[1, 100:103] = np.nan  # a repairable gap is passed over
        gappy[2, :] = np.nan  # a cylinder without a sensor reads NaN
        for q in [*cases, gappy]:
            feat = trace_features(q, c.grid, spec.firing_angles, CFG.flat_tol)
            assert_allclose(feat, trace_features_reference(q, c.grid, spec.firing_angles, CFG.flat_tol),
                            rtol=1e-12, atol=1e-6)
            assert_array_equal(trace_verdict_kernel(feat, CFG.limits, np.empty(3, np.int64)),
                               failures(CFG, feat))


@pytest.mark.parametrize("name,point,seed", [("maruti-3cyl", 0, 7), ("maruti-3cyl", 1, 7), ("deutz-1cyl", 0, 5),
                                             ("deutz-1cyl", 1, 7), ("k9k-4cyl", 0, 7), ("k9k-4cyl", 1, 5),
                                             ("genset-v20", 0, 7), ("genset-v20", 1, 5)])
def test_healthy_runs_are_not_flagged(name, point, seed):
    spec, cyc = cycles_of(name, point, seed, 6)
    assert cyc
    assert flags_over(spec, cyc) == [((), False)] * len(cyc)


def test_calibration_errors_are_not_a_broken_sensor():
    """Pegging up to +-10 bar, a 5 % gain, a 1.2 deg TDC offset: the calibration watches' business, not this check's."""
    for effects in ([PressureOffset(pa=10e5, cylinder=2)], [PressureOffset(pa=-10e5, cylinder=2)],
                    [PressureGain(gain=1.05, cylinder=2), TdcOffset(deg=1.2, cylinder=1)]):
        spec, cyc = cycles_of("maruti-3cyl", 1, 7, 5, effects=effects)
        assert flags_over(spec, cyc) == [((), False)] * len(cyc), effects


@pytest.mark.parametrize("fault,kind", [("negated", "negated"), ("dead_zero", "dead"), ("dead_const", "dead"),
                                        ("clipped", "clipped"), ("phase_360", "phase"), ("clock_x0.5", "phase")])
def test_each_fault_is_flagged_on_its_cylinder(fault, kind):
    spec, cyc = cycles_of("maruti-3cyl", 0, 5, 5, fault, cyl=3)
    for flags, refused in flags_over(spec, cyc):
        assert flags == (f"sensor_pressure_{kind}_cyl3",) and not refused


def test_spikes_are_named_as_spikes():
    spec, cyc = cycles_of("maruti-3cyl", 1, 5, 8, "spikes", cyl=3)
    seen = {f for flags, _ in flags_over(spec, cyc) for f in flags}
    assert seen <= {"sensor_pressure_spikes_cyl3"}, seen


def test_swapped_and_stuck_and_a_slow_clock():
    spec, cyc = cycles_of("genset-v20", 1, 5, 4, "swapped", cyl=1)  # neighbours 36 deg apart
    assert all(set(f) == {"sensor_pressure_phase_cyl1", "sensor_pressure_phase_cyl2"} for f, _ in flags_over(spec, cyc))
    spec, cyc = cycles_of("k9k-4cyl", 0, 5, 6, "stuck", cyl=4)
    assert flags_over(spec, cyc)[-1] == (("sensor_pressure_dead_cyl4",), False)
    spec, cyc = cycles_of("maruti-3cyl", 1, 7, 6, "clock_x2", cyl=3)
    seen = [f for f, _ in flags_over(spec, cyc)]
    assert all(f and all(x.endswith("_cyl3") for x in f) for f in seen), seen


def run_pipeline(spec, cyc, **kw):
    pipe = CyclePipeline(spec, **kw)
    results = [o.result for o in map(pipe.process, cyc) if o.ok]
    return pipe, results


@pytest.fixture(scope="module")
def healthy_run():
    spec, healthy = cycles_of("maruti-3cyl", 0, 5, 10)
    return spec, run_pipeline(spec, healthy)[1]


@pytest.mark.parametrize("fault", ["dead_const", "negated"])
def test_the_faulty_trace_is_kept_out_of_the_figures(fault, healthy_run):
    """The engine FMEP stays within its sigma of the healthy run's, the faulty cylinder's figure is withheld with
    the flag's words, the others are what they were; with the check left out the figure is many sigma off."""
    spec, ok = healthy_run
    _, bad = cycles_of("maruti-3cyl", 0, 5, 10, fault, cyl=3)
    pipe, got = run_pipeline(spec, bad)
    _, blind = run_pipeline(spec, bad, stages=tuple(s for s in STAGES if not isinstance(s, PressureTrace)))
    ref = ok[-1].smoothed
    assert len(got) == len(ok)
    assert abs(got[-1].smoothed.total_fmep - ref.total_fmep) < ref.total_fmep_sigma
    # left out: cylinder 3's IMEP is 0 or negative, the engine's FMEP further off than with the check
    assert blind[-1].imep[2] < 0.2 * ok[-1].imep[2]
    assert abs(blind[-1].smoothed.total_fmep - ref.total_fmep) > 3 * abs(got[-1].smoothed.total_fmep - ref.total_fmep)
    # with it, cylinder 3's IMEP is its siblings' stand-in (said by the flag), within their cycle-to-cycle spread
    assert_allclose(got[-1].imep[2], ok[-1].imep[2], rtol=0.05)
    _, active, status = end_of_run_status(got)
    assert status.engine.status == end_of_run_status(ok)[2].engine.status
    assert status.cylinders[2].status == "withheld" and "sensor_pressure_" in status.cylinders[2].reason
    assert [s.status for s in status.cylinders[:2]] == [s.status for s in end_of_run_status(ok)[2].cylinders[:2]]
    assert_allclose(got[-1].imep[:2], ok[-1].imep[:2], rtol=0.02)


def test_one_cylinder_is_refused_with_its_reason():
    spec, cyc = cycles_of("deutz-1cyl", 0, 5, 5, "clipped", cyl=1)
    pipe, results = run_pipeline(spec, cyc)
    assert not results
    assert pipe.skipped == {"pressure_implausible: clipped_cyl1": len(cyc)}
    assert KINDS.index("clipped") == pipe.stages["pressure_trace"].kind[0]


def test_a_coarse_converter_on_a_fine_grid_is_not_called_clipped_and_a_rail_still_is(maruti):
    """The rail test is an angle (PressureTraceConfig.flat_deg), not a sample count: a healthy trace on a 0.1-deg
    grid read by a 12-bit converter over 250 bar (0.061 bar a code) holds its rounded peak over more than four
    samples but about a degree; the same trace railed at 60 % of its peak is clipped."""
    spec, cyc = maruti
    c = cyc[2]
    fine = np.linspace(c.grid[0], c.grid[-1], 10 * (c.grid.size - 1) + 1)
    code = 250e5 / 4096
    p = np.stack([np.round(np.interp(fine, c.grid, row) / code) * code for row in c.pressure])
    feat = trace_features(p, fine, spec.firing_angles, CFG.flat_tol)
    samples_at_peak = feat[:, 3] / np.degrees(fine[1] - fine[0])
    assert samples_at_peak.max() > 4  # what a count of 4 samples called clipped
    assert failures(CFG, feat).tolist() == [-1] * spec.n_cyl
    railed = p.copy()
    railed[1] = np.minimum(railed[1], 0.6 * railed[1].max())
    assert failures(CFG, trace_features(railed, fine, spec.firing_angles, CFG.flat_tol)).tolist()[1] == \
        KINDS.index("clipped")


@pytest.mark.parametrize("fault", ["healthy", "dead_zero", "negated"])
def test_a_camless_engine_whose_one_channel_shows_no_firing_tdc_counts_its_cycles_skipped(fault):
    """deutz-1cyl has no cam: its 4-stroke phase comes from its one pressure channel (drivers/assembly/cycle_sync.py).
    A dead or negated channel decides nothing: no cycle comes out, and each is counted ``phase_undecided`` once
    four probe windows in a row decided nothing (it left no cycle and no reason before: seen failing so); a healthy
    channel decides at once and counts none."""
    spec = load_engine("deutz-1cyl")
    rpm, load = POINTS["deutz-1cyl"][0]
    sim = simulate(spec, rpm, load, 10, seed=5)
    cyc, skipped = assembled_cycles(spec, sim.info, lie(sim.records, fault, 1, sim.info.tick_hz, rpm, 5))
    if fault == "healthy":
        assert len(cyc) >= 8 and skipped["phase_undecided"] == 0
    else:
        assert cyc == [] and 4 <= skipped["phase_undecided"] <= 10, skipped


def test_a_stood_in_cylinder_shows_no_pressure_figure_of_its_own():
    """The siblings' mean that stands in for a flagged channel feeds the balance (``imep`` keeps it) but is no
    measurement of that cylinder: ``pressure_figures``, the cycle document, the API's cycle summary and analyze's
    run means show none for it (design note 153; before, its IMEP read the siblings' ~within 5 % as if measured)."""
    from frictionwatch.service.api_views import cycle_summary
    from frictionwatch.service.cmd_analyze import _cylinders_run
    from frictionwatch.service.pipeline import LogAnalysis

    spec, bad = cycles_of("maruti-3cyl", 0, 5, 10, "dead_const", cyl=3)
    _, got = run_pipeline(spec, bad)
    last = got[-1]
    assert "sensor_pressure_dead_cyl3" in last.flags and np.isfinite(last.imep).all()
    imep, pmax, angle = last.pressure_figures()
    assert np.isnan([imep[2], pmax[2], angle[2]]).all() and np.isfinite(imep[:2]).all()
    assert_allclose(imep[:2], last.imep[:2], rtol=0)
    doc = last.to_json()
    assert [c["imep_bar"] is None for c in doc["cylinders"]] == [False, False, True]
    assert cycle_summary("e", last)["imep_bar"][2] is None
    flagged = sum(any(f.endswith("_cyl3") and f.startswith("sensor_pressure_") for f in r.flags) for r in got)
    run = _cylinders_run(doc["cylinders"], LogAnalysis(spec, got, Counter()))
    assert [c["pressure_cycles"] for c in run] == [len(got), len(got), len(got) - flagged]
    assert run[0]["imep_bar"] is not None
