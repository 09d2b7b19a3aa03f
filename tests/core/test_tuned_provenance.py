"""Every tuned number carries its provenance and was not tuned on a case that validates it (issue 26 item 5).

The records (core.tuned): core/discrepancy/tuned.json, core/monitor/tuned.json, service/alert_tuned.json. The
validating cases: the discrepancy matrix and null (bench.bench_discrepancy, bench.discrepancy_null), the mismatch
coverage table (bench.mismatch_coverage) and test (tests/core/test_mismatch_coverage.VALIDATES), and every
simulation a test under tests/ runs whose engine, operating point and seed can be read from its source (literals,
module constants, pytest parametrize lists, the test's own assignments; ``test_cases_read_from_the_tests`` says
how many; a simulation behind a test's helper function is not read). A case equals a tuning case when engine, rpm,
load, seed and the effects' names agree; where a test's effects cannot be read, or a bench's are not listed, any
effects are taken to agree. A test that re-runs a tuning case on purpose is a self-consistency check and says so in
its name (``self_consistency``); it is not counted as validation. NOT_VALIDATING lists, with the reason, the tests
that simulate a tuning case to check the simulator itself, which no tuned number enters.
"""

from __future__ import annotations

import ast
import importlib
import inspect
import itertools
import math
from datetime import date
from pathlib import Path

import pytest
from frictionwatch.core.discrepancy import features, fit, pressure_channel
from frictionwatch.core.discrepancy.tuned import TUNED_PATH
from frictionwatch.core.monitor.calibration import drive_train, tdc, tdc_smoothing, tdc_window
from frictionwatch.core.monitor.checks.condition import ConditionSettings
from frictionwatch.core.monitor.checks.ring_condition import RingConditionSettings
from frictionwatch.core.monitor.identify.estimate import ModelErrorFloor
from frictionwatch.core.monitor.identify.pull_check import PullCheck
from frictionwatch.core.monitor.state import MonitorConfig
from frictionwatch.core.plant.simulate import simulate, start_simulation
from frictionwatch.core.tuned import (
    MONITOR_RECORD,
    UNKNOWN_SEED,
    Case,
    Tuned,
    parse_case,
    read_tuned,
    round_up,
    write_tuned,
)
from frictionwatch.service.alert_config import ALERT_RECORD, AlertConfig

from bench import discrepancy_cases, discrepancy_null, mismatch_coverage
from tests.core import test_mismatch_coverage
from tests.sim_logs import simulate_log

TESTS = Path(__file__).resolve().parents[1]
RECORDS = {"discrepancy": TUNED_PATH, "monitor": MONITOR_RECORD, "alerts": ALERT_RECORD}
ENTRIES = {(rec, name): t for rec, path in RECORDS.items() for name, t in read_tuned(path).items()}
TUNING_BENCHES = ("bench.calibrate_", "bench.discrepancy_null", "bench.discrepancy_sigma")
SIMULATORS = {f.__name__: inspect.signature(f) for f in (simulate, start_simulation, simulate_log,
                                                         mismatch_coverage.simulate_case)}
SELF_CONSISTENCY = "self_consistency"
# hand-set numbers whose tuning cases a validating bench or test runs too, (record, name) -> why: expected to fail
# until re-tuned apart (none at present)
KNOWN_CLASHES: dict[tuple[str, str], str] = {}
NOT_VALIDATING = {
    "core/test_simulate_plant.py::test_integrator_step_convergence": "the plant's integrator step, two cycles; no "
    "monitor stage runs",
}
DEBUG = False


def point(c: Case) -> tuple:
    return c.engine, float(c.rpm), float(c.load), int(c.seed)


def effect_names(effects) -> frozenset[str] | None:
    """The effects' names ('chain_mismatch:stiffness_scale=0.8' -> 'chain_mismatch'); None: not known."""
    return None if effects is None else frozenset(str(e).split(":")[0] for e in effects)


def _effects(call: ast.Call, bound: dict, env: dict) -> frozenset[str] | None:
    """The names of the effects a simulation call adds, and '-name' for each default one it leaves out
    (``without``); none passed and no **options -> healthy (empty); None: not readable."""
    kw = {k.arg: k.value for k in call.keywords if k.arg}
    added, left_out = bound.get("effects", kw.get("effects")), bound.get("without", kw.get("without"))
    if any(k.arg is None for k in call.keywords):
        return None
    names = frozenset() if added is None else _names(added, env)
    if left_out is not None:
        out = _value(left_out, env)
        if names is None or not (isinstance(out, list | tuple | set) and all(isinstance(x, str) for x in out)):
            return None
        names = names | {f"-{x}" for x in out}
    return names


def _names(bound_node: ast.AST, env: dict) -> frozenset[str] | None:
    if isinstance(bound_node, ast.List | ast.Tuple):
        names = []
        for el in bound_node.elts:
            if isinstance(el, ast.Call) and getattr(el.func, "id", "") == "parse_effect" and el.args:
                el = el.args[0]
            v = _value(el, env)
            if not isinstance(v, str):
                return None
            names.append(v)
        return effect_names(names)
    v = _value(bound_node, env)
    return effect_names(v) if isinstance(v, list | tuple) and all(isinstance(x, str) for x in v) else None


def _value(node: ast.AST, env: dict):
    """The value of an argument's source, or None where it cannot be read without running the test."""
    if isinstance(node, ast.Name):
        return env.get(node.id)
    if isinstance(node, ast.Attribute) and node.attr == "spec":  # a model's spec: the model's engine
        return _value(node.value, env)
    if isinstance(node, ast.Call):  # an engine by name, or a model made from one: the engine's name
        func = node.func
        name = getattr(func, "id", "") or getattr(func, "attr", "")
        if name in ("load_engine", "load_model", "from_spec") and node.args:
            return _value(node.args[0], env)
        if name == "with_term" and isinstance(func, ast.Attribute):
            return _value(func.value, env)
        return None
    try:
        return ast.literal_eval(node)
    except ValueError:
        return None


def _module_env(tree: ast.Module | ast.FunctionDef, env: dict | None = None) -> dict:
    """Names bound to a readable value by the top-level statements of a module or function body."""
    env = dict(env or {})
    for stmt in tree.body:
        if isinstance(stmt, ast.Assign) and len(stmt.targets) == 1 and isinstance(stmt.targets[0], ast.Name):
            v = _value(stmt.value, env)
            if v is not None:
                env[stmt.targets[0].id] = v
    return env


def _parametrize_envs(fn: ast.FunctionDef, env: dict) -> list[dict]:
    """One name -> value table per combination of the function's literal parametrize lists."""
    grids = []
    for dec in fn.decorator_list:
        if isinstance(dec, ast.Call) and getattr(dec.func, "attr", "") == "parametrize" and len(dec.args) >= 2:
            names, rows = _value(dec.args[0], env), _value(dec.args[1], env)
            if isinstance(names, str) and isinstance(rows, list | tuple):
                names = [n.strip() for n in names.split(",")]
                grids.append([dict(zip(names, row if len(names) > 1 else (row,), strict=True)) for row in rows])
    return [_module_env(fn, {**env, **{k: v for d in combo for k, v in d.items()}})
            for combo in itertools.product(*grids)]


def cases_in_tests() -> tuple[dict[Case, list[str]], int]:
    """(case -> the tests that simulate it, how many simulation calls could not be read) over tests/; a case's
    ``effects``: the names read, or ("?",) where they could not be."""
    found, unread = {}, 0
    for path in sorted(TESTS.rglob("test_*.py")):
        tree = ast.parse(path.read_text())
        env = _module_env(tree)
        for fn in (n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef) and n.name.startswith("test_")):
            if SELF_CONSISTENCY in fn.name:
                continue
            for call in (n for n in ast.walk(fn) if isinstance(n, ast.Call)):
                sig = SIMULATORS.get(getattr(call.func, "id", ""))
                if sig is None:
                    continue
                for penv in _parametrize_envs(fn, env):
                    try:
                        bound = sig.bind_partial(*call.args, **{k.arg: k.value for k in call.keywords if k.arg})
                    except TypeError:
                        unread += 1
                        continue
                    names = list(sig.parameters)
                    args = {n: _value(bound.arguments[n], penv) if n in bound.arguments else sig.parameters[n].default
                            for n in (names[0], "rpm", "load", "seed")}
                    engine = args[names[0]]
                    if not isinstance(engine, str) or not all(isinstance(args[n], int | float) for n in
                                                              ("rpm", "load", "seed")):
                        unread += 1
                        if DEBUG:
                            print(path.name, fn.name, ast.unparse(call)[:100])
                        continue
                    names = _effects(call, bound.arguments, penv)
                    case = Case(engine, float(args["rpm"]), float(args["load"]), int(args["seed"]),
                                ("?",) if names is None else tuple(sorted(names)))
                    found.setdefault(case, []).append(f"{path.relative_to(TESTS)}::{fn.name}")
    return found, unread


def validating_points() -> dict[tuple, list[tuple[frozenset[str] | None, str]]]:
    """(engine, rpm, load, seed) -> [(effect names or None: any, where it validates)]."""
    out = {}

    def add(key, names, where):
        out.setdefault(key, []).append((names, where))

    for e, spec in discrepancy_cases.ENGINES.items():
        for (rpm, load), s in itertools.product(spec["points"], discrepancy_cases.SEEDS):
            add((e, float(rpm), float(load), int(s)), None, "bench.bench_discrepancy matrix")
    for v in discrepancy_null.VALIDATE + discrepancy_null.FAULTS:
        add((v[0], float(v[1]), float(v[2]), int(v[3])), None, "bench.discrepancy_null VALIDATE/FAULTS")
    for (e, rpm, load), effects in itertools.product(mismatch_coverage.POINTS, mismatch_coverage.CASES.values()):
        add((e, float(rpm), float(load), 1), effect_names(effects), "bench.mismatch_coverage POINTS (seed 1)")
    for c in test_mismatch_coverage.VALIDATES:
        add(point(c), effect_names(c.effects), "tests/core/test_mismatch_coverage.py VALIDATES")
    found, _ = cases_in_tests()
    for c, where in found.items():
        tests = sorted(set(where) - set(NOT_VALIDATING))
        if tests:
            add(point(c), None if c.effects == ("?",) else frozenset(c.effects), ", ".join(tests))
    return out


def clashes(c: Case) -> list[str]:
    """Where a tuning case is validated on."""
    names = effect_names(c.effects)
    return [where for val, where in VALIDATING.get(point(c), []) if val is None or val == names]


VALIDATING = validating_points()


@pytest.mark.parametrize("key", sorted(ENTRIES), ids=lambda k: f"{k[0]}:{k[1]}")
def test_each_number_says_how_it_was_tuned(key):
    t = ENTRIES[key]
    assert key not in KNOWN_CLASHES or t.status == "hand-set", "a number tuned by a bench must be tuned apart"
    assert math.isfinite(t.value) and t.figure and t.on
    date.fromisoformat(t.date)
    cases = t.cases()
    if t.status == "tuned":  # written by the bench that tunes it, on logs whose seeds it names
        assert t.tuned_by.startswith("python -m bench.") and "--write" in t.tuned_by, t.tuned_by
        module = t.tuned_by.split()[2]
        assert module.startswith(TUNING_BENCHES), module
        importlib.import_module(module)
        assert all(c.log or c.seed != UNKNOWN_SEED for c in cases)
    else:  # where it came from, and whether it was tuned apart from its tests (the clash check below decides)
        assert t.tuned_by.startswith("hand-set from "), t.tuned_by


def _known(key):
    """A hand-set number known to clash: expected to fail (strict: once it is re-tuned apart this must be removed)."""
    reason = KNOWN_CLASHES.get(key)
    return pytest.param(key, marks=pytest.mark.xfail(reason=reason, strict=True)) if reason else key


@pytest.mark.parametrize("key", [_known(k) for k in sorted(ENTRIES)], ids=lambda k: f"{k[0]}:{k[1]}")
def test_no_number_was_tuned_on_a_case_that_validates_it(key):
    clash = {str(c): clashes(c) for c in ENTRIES[key].cases() if not c.log and clashes(c)}
    assert not clash, clash


def test_cases_read_from_the_tests():
    """The scan reads the test modules' simulations (a scan that finds nothing would pass every clash check)."""
    found, unread = cases_in_tests()
    assert len(found) >= 20, (len(found), unread)
    assert Case("k9k-4cyl", 1400.0, 0.5, 1) in found and Case("maruti-3cyl", 3000.0, 0.8, 3, ("?",)) in found


def test_the_old_hand_tuning_of_the_floor_would_clash():
    """ModelErrorFloor's k was set by hand on the K9K 1700 / 1100 rpm chain logs at seed 1 that the mismatch test and
    table validate on: the check names them."""
    for old in ("k9k-4cyl 1700 rpm 0.69 seed 1 chain_mismatch:stiffness_scale=0.8,damping_scale=1.2",
                "k9k-4cyl 1100 rpm 0.28 seed 1 chain_mismatch:stiffness_scale=1.2,damping_scale=1.0"):
        assert clashes(parse_case(old))
    assert not clashes(parse_case("k9k-4cyl 1700 rpm 0.69 seed 1 misfire"))  # the test's point, another effect
    assert any("test_ring_condition_sim" in w for w in clashes(parse_case("maruti-3cyl 3000 rpm 0.8 seed 3")))


def test_a_case_reads_back_as_written():
    for text in ("k9k-4cyl 1700 rpm 0.69 seed 1 chain_mismatch:stiffness_scale=0.8,damping_scale=1.2",
                 "genset-v20 1500 rpm 0.75 seed ?", "log E0NOLOAD1", "maruti-3cyl 3000 rpm 0.8 seed 7"):
        assert str(parse_case(text)) == text
    with pytest.raises(ValueError, match="tuning case"):
        parse_case("k9k-4cyl at 1700 rpm")


def test_the_code_uses_the_recorded_numbers():
    disc = read_tuned(TUNED_PATH)
    assert features.NULL_OWN == disc["NULL_OWN"].value and features.NULL_FLOOR == disc["NULL_FLOOR"].value
    assert features.NULL_BALANCE == disc["NULL_BALANCE"].value
    speed = [disc.get(f"FLOOR_RMS_SPEED_{kind}", disc["FLOOR_RMS_SPEED"]).value for kind in ("SHARE", "OWN")]
    assert features.FLOOR_RMS == (*speed, disc["FLOOR_RMS_BALANCE"].value)
    if "EFFECT_REL_ERROR" in disc:
        assert fit.EFFECT_REL_ERROR == disc["EFFECT_REL_ERROR"].value
    if "CHAIN_STIFFNESS_REL" in disc:  # bench/calibrate_chain_bias.py (design note 103)
        assert fit.CHAIN_STIFFNESS_REL == disc["CHAIN_STIFFNESS_REL"].value
        assert fit.CHAIN_REL[("chain_mismatch", "stiffness_scale")] == disc["CHAIN_STIFFNESS_REL"].value
    if "INERTIA_FLOOR_ONE_NODE" in disc:  # bench/calibrate_inertia_floor.py (design note 109)
        assert fit.ONE_NODE_FLOOR[("flywheel_inertia", "inertia_scale")] == disc["INERTIA_FLOOR_ONE_NODE"].value
    assert (pressure_channel.BLOW_BY_SHARE_SCALE, pressure_channel.BLOW_BY_REL, pressure_channel.BLOW_BY_FLOOR_LN) == (
        disc["BLOW_BY_SHARE_SCALE"].value, disc["BLOW_BY_REL"].value, disc["BLOW_BY_FLOOR_LN"].value)
    mon, alerts = read_tuned(MONITOR_RECORD), read_tuned(ALERT_RECORD)
    floor, cfg, cond, ring, alert = (ModelErrorFloor(), MonitorConfig(), ConditionSettings(),
                                     RingConditionSettings(), AlertConfig())
    used = {
        "MODEL_ERROR_COUPLING_PER_MISFIT": floor.coupling_per_misfit, "MODEL_ERROR_MISFIT_FREE": floor.misfit_free,
        "R_SQUARED_FLOOR": cfg.r_squared_floor, "SECOND_WHEEL_MAX_ORDER": cfg.second_wheel_max_order,
        "CONDITION_COMPRESSION_FLOOR": cond.compression_floor, "CONDITION_PEAK_FLOOR": cond.peak_floor,
        "CONDITION_INDICATED_FLOOR": cond.indicated_floor, "CONDITION_BURN_LOG_RATIO": cond.burn_log_ratio,
        "CONDITION_PARTIAL_FRACTION": cond.partial_fraction, "RING_LEAK_ALLOWANCE": ring.leak_allowance,
        "TDC_AFTER_IVC_DEG": tdc.AFTER_IVC_DEG, "TDC_BEFORE_SOC_DEG": tdc.BEFORE_SOC_DEG,
        "TDC_AFTER_EOC_DEG": tdc.AFTER_EOC_DEG, "TDC_BEFORE_EVO_DEG": tdc.BEFORE_EVO_DEG,
        "TDC_SMOOTH_DEG": tdc_smoothing.SMOOTH_DEG, "TDC_SYSTEMATIC_SIGMA_DEG": tdc.SYSTEMATIC_SIGMA_DEG,
        "TDC_UNCALIBRATED_SIGMAS": tdc_window.UNCALIBRATED_SIGMAS,
        "DRIVE_TRAIN_STIFFNESS_FLOOR": drive_train.STIFFNESS_FLOOR,
        "DRIVE_TRAIN_DAMPING_FLOOR": drive_train.DAMPING_FLOOR, "DRIVE_TRAIN_SETTLED": drive_train.SETTLED,
        "PULL_CHECK_KAPPA": PullCheck().kappa, "TOOTH_SPEED_STEP": cfg.tooth_speed_step,
        "CHANGE_INNOVATION_REL_FLOOR": cond.change.rel_floor,
    }
    assert set(used) == set(mon)
    for name, value in used.items():
        assert value == mon[name].value, name
    assert alert.ring_leak_allowance == mon["RING_LEAK_ALLOWANCE"].value
    used_alerts = {"RING_SIBLING_Z": alert.ring_sibling_z, "LEAK_FLOOR": alert.leak_floor,
                   "BAND_WIDTH": alert.band_width, "SETTLE_CYCLES": alert.settle_cycles}
    assert set(used_alerts) == set(alerts)
    for name, value in used_alerts.items():
        assert value == alerts[name].value, name


def test_a_record_is_written_whole_or_not_at_all(tmp_path):
    path = tmp_path / "tuned.json"
    good = Tuned(0.5, "python -m bench.calibrate_x --write", ("k9k-4cyl 1500 rpm 0.45 seed 41",), "a figure",
                 "2026-11-29")
    write_tuned({"A": good}, path)
    write_tuned({"B": Tuned(2.0, "hand-set from x, not yet re-tuned apart", ("log E0NOLOAD1",), "f", "2026-11-29",
                            "hand-set")}, path)
    back = read_tuned(path)
    assert back["A"] == good and back["B"].status == "hand-set" and back["B"].value == 2.0
    before = path.read_text()
    with pytest.raises(ValueError, match="tuning case"):
        write_tuned({"C": Tuned(1.0, "python -m bench.calibrate_x --write", ("k9k at 1500",), "f", "2026-11-29")}, path)
    assert path.read_text() == before and [p.name for p in tmp_path.iterdir()] == ["tuned.json"]
    unseeded = Tuned(1.0, "python -m bench.calibrate_x --write", ("k9k-4cyl 1500 rpm 0.45 seed ?",), "f", "2026-11-29")
    with pytest.raises(ValueError, match="'D' is tuned but names a log without its seed"):
        write_tuned({"D": unseeded}, path)
    assert path.read_text() == before


def test_a_floor_is_rounded_up_never_down():
    assert round_up(0.0347) == 0.035 and round_up(0.0107) == 0.011 and round_up(1.2435) == 1.3
    assert round_up(0.012) == 0.012 and round_up(0.0) == 0.0 and round_up(-0.0347) == -0.035
