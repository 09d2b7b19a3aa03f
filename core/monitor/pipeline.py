"""The one pipeline of the monitor: a model and its assembled cycles in, one typed outcome per cycle out.

    pipe = CyclePipeline(model, config)          # an EngineModel (effects, calibration) or an EngineSpec
    for cycle in cycles:
        outcome = pipe.process(cycle)             # CycleOutcome: a result, or the reason there is none
    # or: for outcome in run_cycles(model, cycles, config): ...

What a cycle goes through, in order:
1. the stages of ``STAGES`` placed ``BEFORE_VIEW``: the pressure-trace plausibility check
   (core.monitor.checks.pressure_trace), which flags a channel that is no cylinder's pressure (dead, clipped,
   negated, out of phase), puts its healthy siblings' trace in its place, or refuses the cycle
   (``pressure_implausible``) where no sibling can stand in; it reads the pressure as it came, before any view;
2. the model's view (core.model.view): the pressure corrected for the model's sensor effects, the phases its TDC
   offsets state, its loss terms; made at the first cycle when a friction shape is sized at an operating point;
3. the monitor (core.monitor.monitor.process_cycle): teeth, balance, identify, checks, report;
4. the stages of ``STAGES`` placed ``AFTER_MONITOR``: the calibration watches (TDC from the pressure, each channel's
   gain and pegging), judged against the model's calibration; their flags are added to the cycle's result (and
   withhold the figures they touch).
Every stage is a ``Stage``: ``initial(spec) -> state`` and ``update(state, StageInput) -> StageOutput`` (its new
state, its flags for the cycle, and -- before the view only -- the cycle to go on with or why it goes no further),
and its ``place``. Adding one is one class and one line in ``STAGES``, which is also their order within a place
(and, for a stage whose kernels come only after many cycles, a ``warm_up()`` that reaches them in a few:
core.monitor.warmup). Each stage's state is kept by its name and carried across a restart (``carried``/``resume``).

service.pipeline puts the cycle assembler (drivers/) in front: analyze, serve, reanalyze and commission run that,
and the discrepancy workflow runs its models through ``run_cycles``. A cycle the monitor refuses is an outcome with
its reason, never an exception; an unexpected numeric failure is one too (``monitor_error: <type>``), logged once.
"""

from __future__ import annotations

import dataclasses
import logging
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, replace
from typing import Any, ClassVar, Protocol

import numpy as np
from frictionwatch.core.model.calibration import Calibration
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.model.engine_model import EngineModel, as_model
from frictionwatch.core.model.view import MonitorView, Reference, monitor_view, needs_reference, reference, viewed_cycle
from frictionwatch.core.monitor.calibration.gain_watch import GainWatchState, watch_gains
from frictionwatch.core.monitor.calibration.tdc import BLOCKS, TdcEstimate
from frictionwatch.core.monitor.calibration.tdc_watch import (
    CYLINDERS_PER_WINDOW,
    WINDOW_CYCLES,
    TdcWatchState,
    watch_cycle,
)
from frictionwatch.core.monitor.calibration.tdc_window import close_window
from frictionwatch.core.monitor.calibration.thermal_shock_watch import (
    ThermalShockWatchState,
    judged_cylinders,
    judged_flags,
    watch_expansion,
)
from frictionwatch.core.monitor.checks.pressure_trace import PressureTraceConfig, PressureTraceState, check_traces
from frictionwatch.core.monitor.monitor import CycleRejected, initial_state, nonpositive_flags, process_cycle
from frictionwatch.core.monitor.report.results import CycleResult
from frictionwatch.core.monitor.state import MonitorConfig, MonitorState
from frictionwatch.core.types import Cycle

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class CycleOutcome:
    """What became of one cycle: its ``result``, or why there is none (``skipped``: the reason, e.g.
    'operating_point' from the monitor, 'data_gap' from the assembler; ``stage``: 'monitor' or 'assembly').
    ``index`` is the cycle's number (None for an assembler skip, which has no cycle)."""

    index: int | None
    result: CycleResult | None = None
    skipped: str | None = None
    stage: str = "monitor"

    @property
    def ok(self) -> bool:
        return self.result is not None


BEFORE_VIEW = "before_view"  # a stage's place: on the cycle as it came, before the model's view and the monitor
AFTER_MONITOR = "after_monitor"  # on the analysed cycle and its result


@dataclass(frozen=True)
class StageInput:
    """What a stage sees of a cycle: the spec its phases are in (the model's before the view, the view's after it),
    the model's calibration, the cycle (as it came before the view; as the monitor got it after), and after the
    monitor only: its result and each throw's static twist ahead of the flywheel (z,) rad in the monitor's model of
    this cycle (None before the view), and each throw's angle against the flywheel over the cycle (static twist and
    its harmonics, core.monitor.checks.ring_pressure.ThrowMotion; None before the view and on a rigid shaft line),
    and the flags raised on this cycle before the stage (the result's and the earlier stages')."""

    spec: EngineSpec
    calibration: Calibration
    cycle: Cycle
    result: CycleResult | None = None
    twist: np.ndarray | None = None
    motion: Any = None  # core.monitor.checks.ring_pressure.ThrowMotion | None
    flags: tuple[str, ...] = ()


@dataclass(frozen=True)
class StageOutput:
    """What a stage made of one cycle: its new ``state`` (carried to the next cycle), the ``flags`` it raises on this
    cycle (added to the cycle's before the view, to the result's after the monitor), and -- a stage before the view
    only -- the ``cycle`` the rest of the pipeline sees in the input's place (None: the input's) or the ``refusal``,
    why the cycle goes no further (a skipped outcome's reason); a stage after the monitor that gives either is a
    programming error (TypeError), not a cycle's outcome."""

    state: Any
    flags: tuple[str, ...] = ()
    cycle: Cycle | None = None
    refusal: str | None = None


class Stage(Protocol):
    """One stage of the pipeline (module doc), at its ``place`` (BEFORE_VIEW or AFTER_MONITOR); its state is kept by
    ``name``. A stage that reads in windows has ``last`` on its state (the newest window's reading, a new object when
    a window closes) and may have ``close(state, spec, calibration) -> state`` to read its open window now
    (``CyclePipeline.close_windows``)."""

    name: str
    place: str

    def initial(self, spec: EngineSpec) -> Any: ...

    def update(self, state: Any, inp: StageInput) -> StageOutput: ...


@dataclass(frozen=True)
class TdcWatch:
    """TDC from the pressure, window by window, against the calibration (core.monitor.calibration: tdc_watch the
    per-cycle sums, tdc_window the window's reading): windows of ``window`` cycles, ``per_window`` cylinders fitted
    per window in turn (an offline run that wants one reading of every cylinder over the whole log: the engine's
    cylinders, a window longer than the log, and ``CyclePipeline.close_windows`` at its end). ``fit``: what gives the
    window's fits (tdc_window.close_window's; an offline caller's memo, core.monitor.calibration.tdc_memo)."""

    per_window: int = CYLINDERS_PER_WINDOW
    window: int = WINDOW_CYCLES
    fit: Callable[..., TdcEstimate] | None = None
    name: ClassVar[str] = "tdc_watch"
    place: ClassVar[str] = AFTER_MONITOR

    def initial(self, spec: EngineSpec) -> TdcWatchState:
        return TdcWatchState.empty()

    def update(self, state: TdcWatchState, inp: StageInput) -> StageOutput:
        """The cycle added (tdc_watch); a full window read (tdc_window): a cycle enters the reading's file only then."""
        state = watch_cycle(inp.spec, state, inp.cycle, inp.twist)
        if state.cycles >= self.window:
            state = close_window(inp.spec, inp.calibration, state, per_window=self.per_window, fit=self.fit)
        return StageOutput(state, state.flags)

    def close(self, state: TdcWatchState, spec: EngineSpec, calibration: Calibration) -> TdcWatchState:
        """The open window read now (``CyclePipeline.close_windows``)."""
        return close_window(spec, calibration, state, per_window=self.per_window, fit=self.fit)

    def warm_up(self) -> TdcWatch:
        """This watch with windows of BLOCKS cycles, the fewest a window reads (core.monitor.warmup): its fits
        within a warm-up's few cycles."""
        return dataclasses.replace(self, window=BLOCKS)


@dataclass(frozen=True)
class GainWatch:
    """Each channel's gain and pegging against its siblings (core.monitor.calibration.gain_watch), judged every
    ``window`` cycles."""

    window: int = WINDOW_CYCLES
    name: ClassVar[str] = "gain_watch"
    place: ClassVar[str] = AFTER_MONITOR

    def initial(self, spec: EngineSpec) -> GainWatchState:
        return GainWatchState.empty()

    def update(self, state: GainWatchState, inp: StageInput) -> StageOutput:
        state = watch_gains(inp.spec, inp.calibration, state, inp.cycle, inp.twist, self.window)
        return StageOutput(state, state.flags)

    def warm_up(self) -> GainWatch:
        """This watch judging every BLOCKS cycles (core.monitor.warmup)."""
        return dataclasses.replace(self, window=BLOCKS)


@dataclass(frozen=True)
class ThermalShockWatch:
    """Each channel's expansion bend against its siblings' (core.monitor.calibration.thermal_shock_watch): a
    thermal-shocked sensor, judged every ``window`` cycles."""

    window: int = WINDOW_CYCLES
    name: ClassVar[str] = "thermal_shock_watch"
    place: ClassVar[str] = AFTER_MONITOR

    def initial(self, spec: EngineSpec) -> ThermalShockWatchState:
        return ThermalShockWatchState.empty()

    def update(self, state: ThermalShockWatchState, inp: StageInput) -> StageOutput:
        """Not judged where a TDC offset flagged on the cycle moves the throws' motion it reads
        (thermal_shock_watch.judged_cylinders): no flag of those cylinders then."""
        judged = judged_cylinders(inp.flags, inp.spec.n_cyl)
        state = watch_expansion(inp.spec, state, inp.cycle, inp.twist, self.window, inp.motion, judged)
        return StageOutput(state, judged_flags(state.flags, judged))

    def warm_up(self) -> ThermalShockWatch:
        """This watch judging every BLOCKS cycles (core.monitor.warmup)."""
        return dataclasses.replace(self, window=BLOCKS)


@dataclass(frozen=True)
class PressureTrace:
    """Each channel's trace checked for being a cylinder's pressure at all (core.monitor.checks.pressure_trace)
    before the view and the monitor: its flags join the cycle's, a flagged trace is replaced by its siblings',
    and a cycle with no sibling to stand in is refused with the reason ``pressure_implausible``."""

    config: PressureTraceConfig = PressureTraceConfig()
    name: ClassVar[str] = "pressure_trace"
    place: ClassVar[str] = BEFORE_VIEW

    def initial(self, spec: EngineSpec) -> PressureTraceState:
        return PressureTraceState.empty(spec.n_cyl)

    def update(self, state: PressureTraceState, inp: StageInput) -> StageOutput:
        cycle = inp.cycle
        state, pressure, flags, refuse = check_traces(self.config, state, cycle.pressure, cycle.grid,
                                                      inp.spec.firing_angles)
        if refuse:  # the reason names the channels and what is wrong with them: "pressure_implausible: dead_cyl1"
            return StageOutput(state, refusal="pressure_implausible: " + ", ".join(
                f.removeprefix("sensor_pressure_") for f in flags))
        if not flags:  # the cycle itself goes on (nothing copied)
            return StageOutput(state)
        return StageOutput(state, flags, replace(cycle, pressure=pressure))


STAGES: tuple[Stage, ...] = (PressureTrace(), TdcWatch(), GainWatch(), ThermalShockWatch())


def monitor_config(view: MonitorView, config: MonitorConfig | None) -> MonitorConfig:
    """The caller's config with what the view decides: the model's calibration, its known load ripple, and constant
    inertia where the model has no ``variable_inertia``."""
    cfg = dataclasses.replace(config or MonitorConfig(), calibration=view.calibration, load_ripple=view.load_ripple)
    return cfg if view.variable_inertia else dataclasses.replace(cfg, variable_inertia=False)


class CyclePipeline:
    """One engine's cycles through the stages, the view and the monitor (module doc); state explicit in its
    attributes: ``state`` the monitor's, ``stages`` each stage's by name, ``skipped`` the refusals by reason,
    ``cycles_ok`` the analysed count.

    ``reference``: the operating point a friction shape is sized at (None: the first cycle's); ``on_cycle`` sees
    each cycle as the monitor gets it (commissioning reads its pressure); ``stages``: the stages in order (STAGES;
    a warm-up's, core.monitor.warmup; a bench's without one)."""

    def __init__(self, engine: EngineModel | EngineSpec, config: MonitorConfig | None = None,
                 reference: Reference | None = None, on_cycle: Callable[[Cycle], None] | None = None,
                 stages: tuple[Stage, ...] = STAGES):
        self.model = as_model(engine)
        self.spec = self.model.spec
        self.config = config or MonitorConfig()
        self.on_cycle = on_cycle
        for stage in stages:
            if stage.place not in (BEFORE_VIEW, AFTER_MONITOR):
                raise ValueError(f"stage {stage.name}: its place {stage.place!r} is neither {BEFORE_VIEW} nor "
                                 f"{AFTER_MONITOR}")
        self.stage_order = stages
        self.view: MonitorView | None = None
        self.view_corrects = False
        self.reference: Reference | None = None
        self.monitor_model: EngineModel | None = None
        self.monitor_cfg: MonitorConfig | None = None
        self.state: MonitorState | None = None
        self.stages = {s.name: s.initial(self.spec) for s in stages}
        self.stage_cycle: dict[str, int] = {}  # the cycle that closed each stage's newest window (its ``last``)
        self.skipped: Counter[str] = Counter()
        self.cycles_ok = 0
        self.newest_cycle: int | None = None  # the index of the newest cycle the state holds (None: none since made)
        if reference is not None or not needs_reference(self.model):
            self._make_view(reference)

    def _make_view(self, ref: Reference | None) -> None:
        self.reference = ref
        self.view = monitor_view(self.model, ref)
        # whether the view corrects the pressure, read once per view (it is frozen): the test is two array
        # comparisons, ~2 % of a k9k cycle when made twice a cycle
        self.view_corrects = self.view.corrects_pressure
        self.monitor_model = self.view.model
        self.monitor_cfg = monitor_config(self.view, self.config)
        self.state = initial_state(self.monitor_model, self.monitor_cfg)

    def cylinder_twist(self) -> np.ndarray:
        """(z,) [rad] each throw's static twist ahead of the flywheel in the monitor's model of the newest cycle (its
        harmonic balance's m = 0 term); zeros on a rigid shaft line or before the first cycle."""
        st = self.state
        if st is None or st.static is None or st.op is None or st.static.shape[0] != st.op.cylinders.n_nodes:
            return np.zeros(self.spec.n_cyl)
        return np.asarray(st.static[st.op.cylinders.node], dtype=np.float64)

    def process(self, cycle: Cycle) -> CycleOutcome:
        cycle, _, refusal = self._run_stages(BEFORE_VIEW, StageInput(self.spec, self.model.calibration, cycle))
        if refusal is not None:
            return self._skip(cycle, refusal)
        if self.view is None:
            self._make_view(reference([cycle]))
        view = self.view
        if self.view_corrects:  # a clipped floor is read before the correction lifts it off zero
            low = [f for f in nonpositive_flags(cycle.pressure) if f not in cycle.flags]
            cycle = replace(cycle, flags=cycle.flags + tuple(low)) if low else cycle
            cycle = viewed_cycle(view, cycle)  # (the cycle itself where nothing is corrected)
        if self.on_cycle is not None:
            self.on_cycle(cycle)
        try:
            self.state, result = process_cycle(self.monitor_model, self.state, cycle, self.monitor_cfg)
        except CycleRejected as exc:
            return self._skip(cycle, exc.reason)
        except (ValueError, FloatingPointError, ArithmeticError) as exc:
            # an unexpected numeric failure: counted and logged with its text, the stream goes on
            log.warning("cycle %d: %s", cycle.index, exc)
            return self._skip(cycle, f"monitor_error: {type(exc).__name__}")
        self.cycles_ok += 1
        self.newest_cycle = int(cycle.index)
        inp = StageInput(view.spec, self.model.calibration, cycle, result, self.cylinder_twist(), self.state.motion,
                         result.flags)
        _, flags, _ = self._run_stages(AFTER_MONITOR, inp)
        new = tuple(f for f in flags if f not in result.flags)
        if new:
            result = replace(result, flags=result.flags + new)
        return CycleOutcome(int(cycle.index), result)

    def _run_stages(self, place: str, inp: StageInput) -> tuple[Cycle, tuple[str, ...], str | None]:
        """The stages at ``place`` in their order over ``inp``, each state kept: (the cycle as the last of them left
        it, their flags each once in order, the first refusal or None). Before the view a stage's flags join the
        cycle it passes on (the next stage and the monitor see them), and a refusal stops the cycle there."""
        cycle = inp.cycle
        flags: dict[str, None] = {}
        for stage in self.stage_order:
            if stage.place != place:
                continue
            before = self.stages[stage.name]
            out = stage.update(before, inp)
            self.stages[stage.name] = out.state
            if getattr(out.state, "last", None) is not getattr(before, "last", None):  # a window closed: its reading
                self.stage_cycle[stage.name] = int(cycle.index)
            flags.update(dict.fromkeys(out.flags))
            if place != BEFORE_VIEW:  # after the monitor a stage's flags are all it says of the cycle
                if out.cycle is not None or out.refusal is not None:
                    raise TypeError(f"stage {stage.name} after the monitor gave a cycle or a refusal: only a stage "
                                    "before the view may")
                new = tuple(f for f in out.flags if f not in inp.flags)
                inp = replace(inp, flags=inp.flags + new) if new else inp  # the next stage sees them
                continue
            if out.refusal is not None:
                return cycle, tuple(flags), out.refusal
            if out.cycle is not None or out.flags:
                cycle = out.cycle if out.cycle is not None else cycle
                new = tuple(f for f in out.flags if f not in cycle.flags)
                cycle = replace(cycle, flags=cycle.flags + new) if new else cycle
                inp = replace(inp, cycle=cycle)
        return cycle, tuple(flags), None

    def carried(self) -> dict | None:
        """What this pipeline carries from one cycle to the next, as plain values (None before the first cycle): the
        reference the view was sized at, the monitor's state without what the model rebuilds (``layout``: the
        model's terms; ``op``: the operating point, rebuilt at the next cycle as at a first one), each stage's
        state and the cycle that closed its newest window, and the config they were made with."""
        if self.view is None or self.state is None:
            return None
        return {"reference": self.reference, "state": replace(self.state, layout=None, op=None),
                "stages": dict(self.stages), "stage_cycle": dict(self.stage_cycle), "config": self.config}

    def resume(self, carried: dict) -> None:
        """Go on from ``carried()`` of an earlier pipeline of the same model and config (ValueError otherwise): the
        view sized again at its reference, the state's layout from this model."""
        if carried["config"] != self.config:
            raise ValueError("the monitor's settings differ from those the carried state was made with")
        self._make_view(carried["reference"])
        state = carried["state"]
        if state.params.shape != self.state.params.shape:
            raise ValueError(f"the carried state has {state.params.shape[0]} parameters, this model "
                             f"{self.state.params.shape[0]}")
        self.state = replace(state, layout=self.state.layout, op=None)
        self.stages = {**self.stages, **carried["stages"]}
        self.stage_cycle = dict(carried["stage_cycle"])

    def close_windows(self) -> None:
        """Every stage that reads in windows and can (a ``close`` method) reads its open window now: a run
        that ends mid-window (an offline log shorter than the TDC watch's 100 cycles) still gets its reading. Not
        called while serving: there a window closes when it is full."""
        if self.view is None:
            return
        for stage in self.stage_order:
            close = getattr(stage, "close", None)
            if close is not None:
                self.stages[stage.name] = close(self.stages[stage.name], self.view.spec, self.model.calibration)

    def _skip(self, cycle: Cycle, reason: str) -> CycleOutcome:
        if self.skipped[reason] == 0:
            log.warning("cycle %d skipped: %s", cycle.index, reason)
        self.skipped[reason] += 1
        return CycleOutcome(int(cycle.index), skipped=reason)


def run_cycles(engine: EngineModel | EngineSpec, cycles: Iterable[Cycle], config: MonitorConfig | None = None,
               reference: Reference | None = None) -> Iterator[CycleOutcome]:
    """Every cycle's outcome, in order (``CyclePipeline`` over ``cycles``)."""
    pipe = CyclePipeline(engine, config, reference)
    for cycle in cycles:
        yield pipe.process(cycle)


__all__ = ["AFTER_MONITOR", "BEFORE_VIEW", "STAGES", "CycleOutcome", "CyclePipeline", "GainWatch", "PressureTrace",
           "Stage", "StageInput", "StageOutput", "TdcWatch", "ThermalShockWatch", "monitor_config", "run_cycles"]
