"""The monitor's configuration and the state it carries from cycle to cycle (core.monitor.monitor), in a module of
their own so that the stages (core.monitor.identify.identification, core.monitor.report.cycle_report) can take them without
importing the monitor."""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from frictionwatch.core.model.calibration import Calibration
from frictionwatch.core.monitor.balance.harmonic_balance import OperatingPoint
from frictionwatch.core.monitor.checks.change import ChangeDetector
from frictionwatch.core.monitor.checks.ring_pressure import RingTables, ThrowMotion
from frictionwatch.core.monitor.checks.sensor_health import SensorHealthConfig, SensorHealthState
from frictionwatch.core.monitor.identify.accumulate import Accumulator
from frictionwatch.core.monitor.identify.estimate import ModelErrorFloor
from frictionwatch.core.monitor.identify.noise_model import ResidualStats
from frictionwatch.core.monitor.identify.parameters import ParameterLayout, PriorNormal
from frictionwatch.core.monitor.identify.pull_check import PullCheck
from frictionwatch.core.monitor.teeth.flywheel import LearnerSettings, ToothLearner
from frictionwatch.core.monitor.teeth.tooth_fit import SecondWheelState, ToothPatterns
from frictionwatch.core.tuned import MONITOR_RECORD, read_tuned
from frictionwatch.core.types import Cycle

_TUNED = read_tuned(MONITOR_RECORD)  # the tuned defaults below, with their provenance (core.tuned)


@dataclass(frozen=True)
class MonitorConfig:
    """Hyper-parameters of the monitor (all have defaults that suit the presets).

    max_order: highest engine order used in the identification (None: from the wheel, <= 12)
    fit_order: highest order fitted to the teeth (None: max_order); fit_drift: fit a linear speed drift per cycle
    (off: over one cycle it is nearly collinear with order 0.5 and drags in content from above the band)
    drift_nuisance: instead, treat each cycle's linear speed drift as a random effect of that cycle's equations (its
    shape passed through the same tooth fit, its prior size from the cycle-to-cycle mean-speed steps), so speed
    changes between cycles neither bias nor add noise to the estimate
    time_samples: samples per cycle of the harmonic-balance time grid (192 = 8x the highest harmonic at M = 24).
    Against 256: per-cylinder errors within 0.5 points (K9K, Maruti; V20 within its sigma), total FMEP within 0.1
    point, deutz NRMSE within 0.5 point; 128 shifted the K9K total by up to -0.25 point (the friction terms' sharp
    features alias into the band), 512 moved nothing beyond noise
    scheme, prior_coefficients: parameter grouping and baseline a0 (core.monitor.identify.parameters.parameter_layout)
    forgetting: per-cycle factor of the accumulated equations, 1 - 1/N_window (None: from ``forgetting_time_s``)
    forgetting_time_s: time constant [s of running] of the accumulated equations, sized to the wear time scale: the
    window is N_window = max(400, 100 z, tau / T_cycle) cycles (more cylinders need more cycles, physics.md §12.5;
    never shorter than that cycle rule). Default 4 h (genset-v20 at 1500 rpm: 180,000 cycles): rings wear over days,
    so a gradual wear lags the estimate by about its rate x tau (a +30 % wear over three days: 1.7 %), while a step
    change is followed through the change detector's discount (core.monitor.checks.change); bench/accuracy_v20_long.py and
    docs/information.md. None: the cycle rule alone (the window of 2,000 cycles, 80 s, on genset-v20)
    noise_memory: EWMA factor of the residual statistics that whiten the equations
    share_spread: 1-sigma of the Eq. 6 sharing prior, relative; parameter_sigma: weak prior on each scale (params ~ 1)
    sibling_spread: 1-sigma of a per-cylinder scale about the mean of its siblings (0: no sibling prior)
    model_rel_error: repeatable model error of a speed harmonic, relative to its size (physics.md §12.3: 0.2 %)
    balance_rel_error: repeatable error of the mean balance relative to T_iM (pressure gain/TDC, load sensor)
    coupling_rel_error: relative error of the modelled damper/coupling dissipation
    load_rel_error: load-sensor accuracy as a fraction of the rated torque (a class-0.05 torque flange: 0.05 %)
    resolve_rel: a per-cylinder mean is reported when its 1-sigma is at most this fraction of it
    coefficient_snr: a coefficient is reported when it exceeds this many sigmas
    min_data_gain: ... and either only when the speed signal, not the priors, gave at least this share of what is
    known about it (core.monitor.identify.posterior.Posterior.data_gain; for a cylinder: its deviation from the equal share)
    passes: harmonic-balance passes per cycle; rebuild_tolerance: relative Omega change that rebuilds Z^-1
    tooth_nuisance: carry the in-band tooth-spacing error (integer orders) as accumulated nuisance parameters with
    a prior from ``tooth_error_deg``, the expected rms per-tooth angle error (core.monitor.identify.parameters.tooth_patterns)
    variable_inertia: model J(theta) and the mass torque (off only to analyse a plant without them)
    learn_teeth: learn the out-of-band tooth pattern from the fit residuals (core.monitor.teeth.flywheel.ToothLearner) with EWMA
    factor ``tooth_memory``; the fit is repeated with the fresh correction for the first ``tooth_refit_cycles``
    tooth_speed_step: a cycle whose mean speed moved more than this fraction from the last fitted one's is not learnt from
    warmup_cycles: cycles whose equations are not accumulated (the tooth learner and noise model settle first)
    sensor_health: TDC, pressure gain and offset checks and corrections (core.monitor.checks.sensor_health); None: off
    model_error_floor: the systematic sigma the equations cannot see (core.monitor.identify.estimate.ModelErrorFloor),
    tuned on chain-mismatch logs apart from those that validate it (bench/calibrate_model_error_floor.py)
    pull_check: the smoothed figures' pull check (core.monitor.identify.pull_check.PullCheck: its kappa, tuned apart
    from the logs that validate it, bench/calibrate_pull_check.py)
    calibration: how well TDC, pressure gain and J are known (core.model.calibration; the model's, through
    core.model.view): its remaining uncertainty is added to every friction sigma. The default is an
    uncalibrated installation's, never perfect sensors
    r_squared_floor: a cycle whose speed fit explains less of the speed ripple is flagged ``speed_fit_poor``: what
    rests on the speed signal (the per-cylinder split) is not supported by it. Tuned by
    bench/calibrate_r_squared_floor.py (core/monitor/tuned.json: the logs and figure) between 24-cycle simulated logs
    of every preset but k9k, seeds 51-52 (lowest: genset-v20, 0.115, its ripple near the sensor noise) and TU/e
    E0NOLOAD1 (0.019-0.027); tested on E0NOLOAD2-4 (flagged) and the other group14 files (0.08-0.87, not flagged:
    R^2 alone does not separate them from the healthy simulated genset)
    """

    max_order: float | None = None
    fit_order: float | None = None
    fit_drift: bool = False
    drift_nuisance: bool = True
    time_samples: int = 192
    scheme: str | None = None
    prior_coefficients: np.ndarray | None = None
    forgetting: float | None = None
    forgetting_time_s: float | None = 4.0 * 3600.0
    noise_memory: float = 1.0 - 1.0 / 100.0
    share_spread: float = 0.3
    sibling_spread: float = 0.15
    parameter_sigma: float = 1.0
    model_rel_error: float = 0.003
    # the chain's modes whose free response keeps at least this much of its amplitude over one cycle are a random
    # effect of each cycle's speed rows, of the prior variance the data give (core.monitor.identify.free_response;
    # 0: none). A physical cut, not tuned on the figures: genset-v20 at 1500 rpm carries 0.74 (2.4 Hz) and 0.32
    # (19.6 Hz), its next in-band mode 0.002 (87 Hz; those above the band are left out), so any value in
    # 0.003-0.3 takes the same two; maruti-3cyl's 39.5 Hz mode keeps 0.44 at 5400 rpm (design notes 105, 108)
    free_response_carry: float = 0.1
    balance_rel_error: float = 0.001
    coupling_rel_error: float = 0.1
    load_rel_error: float = 5e-4
    resolve_rel: float = 0.10
    coefficient_snr: float = 2.0
    min_data_gain: float = 0.5
    passes: int = 2
    rebuild_tolerance: float = 0.005
    tooth_nuisance: bool = True
    tooth_error_deg: float = 0.05
    learn_teeth: bool = True
    variable_inertia: bool = True
    tooth_memory: float = 1.0 - 1.0 / 100.0
    tooth_refit_cycles: int = 50
    # the learner skips a cycle whose mean speed moved more than this (relative) from the previous fitted cycle's: a
    # speed step's settling leaves in the residual what the band cannot follow, at the same wheel positions at every
    # step (design note 60). Hand-set, core/monitor/tuned.json: twice the largest change between steady cycles of
    # one-point logs (seed 11); validated on the two-point matrix logs (seeds 2, 3) and one more (tests/core)
    tooth_speed_step: float = _TUNED["TOOTH_SPEED_STEP"].value
    warmup_cycles: int = 20
    # off by default until its speed-based TDC holds where the model is not the engine (issue 16): on, the merged
    # monitor read the healthy K9K 1400 rpm / half-load FMEP -7.8 % (target 2 %), moved the real TU/e IMEP off the
    # DAQ's own, and its common-mode sigma hid the worn-ring cylinders' excess; MonitorConfig(sensor_health=
    # SensorHealthConfig()) turns it on
    sensor_health: SensorHealthConfig | None = None
    model_error_floor: ModelErrorFloor = ModelErrorFloor()
    pull_check: PullCheck = PullCheck()
    calibration: Calibration = Calibration()
    r_squared_floor: float = _TUNED["R_SQUARED_FLOOR"].value
    # a known load-torque ripple at the load node (the model's load_ripple effect, core.model.view): amplitude [N m],
    # fraction of the measured mean load torque (where the amplitude is 0), engine order, phase [rad]; zeros: none
    load_ripple: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    # the joint fit of both wheels: the second wheel's half-order speed equations accumulated with the flywheel's
    # (core.monitor.identify.noise_model; its node: the engine file's [sensors.second_wheel]). Off by default.
    # Since its rows are weighted by their repeatable error (design note 35) it measures as many genset-v20 cylinders
    # as one wheel or a few more, but not more of them right (note 38; +-20 % profile, within 5 % and 2 sigma at
    # 4,000 cycles: seeds 29 / 31 / 37 / 43 joint 12 / 13 / 15 / 12, one wheel 10 / 15 / 15 / 12; the 16 not
    # met), and it has figures outside 2 sigma on three of those four seeds (held-out seed 37: 4 of 381; one wheel 0
    # of 295): both wheels' repeated model error sets its sigma, the second wheel lowers the statistical part by
    # 1-17 % where the information analysis expects 3-9x. It also costs about twice a one-wheel cycle (19-21x real
    # time measured in session 13, against the 30x the two-wheel path must keep). So it stays off.
    # The second wheel's own speed and tooth learning run whatever this says.
    second_wheel: bool = False
    # the highest half order of the free end's equations in the joint fit (hand-set, core/monitor/tuned.json):
    # 4.5, the highest whose residual at the
    # true scales is within 1.5 standard errors on genset-v20 (bench/second_wheel_consistency.py, seed 7, load
    # 0.75, 120 cycles; 5.5: 3.4, 8.5: 17.5 standard errors). Not validated: on seed 29 (+-20 % profile,
    # bench/accuracy_v20_wheels.py --cycles 2000) the joint fit with it measured 3 cylinders, 0 within 5 % and 2 sigma,
    # against one wheel's 9 and 6
    second_wheel_max_order: float = _TUNED["SECOND_WHEEL_MAX_ORDER"].value
    # keep each two-wheel cycle's drive-train identification inputs (CycleResult.chain: node torques, flywheel speed
    # and patterns): what commissioning reads (core.monitor.calibration.drive_train); off when serving, where nothing
    # reads them (32 us a genset-v20 two-wheel cycle)
    drive_train_inputs: bool = False
    # each cycle's spread of the residual speed harmonics that the tooth nuisances' posterior still carries
    # (CycleResult.residual_pattern_sigma, core.monitor.teeth.pattern_spread): what the discrepancy workflow's null
    # reads (design note 118); off when serving, where nothing reads it
    nuisance_spread: bool = False

    def __post_init__(self) -> None:
        tau = self.forgetting_time_s
        if tau is not None and not (isinstance(tau, int | float) and 0.0 < tau < float("inf")):
            raise ValueError(f"forgetting_time_s = {tau!r} must be a positive number of seconds, or None")
        lam = self.forgetting
        if lam is not None and not (isinstance(lam, int | float) and 0.0 <= lam <= 1.0):
            raise ValueError(f"forgetting = {lam!r} must be a per-cycle factor in [0, 1], or None")
        # the tooth learner's settings as the tooth fit takes them (core.monitor.teeth.tooth_fit.fit_cycle_teeth):
        # a constant of the config, made once here, not by a property every cycle (an attribute, not a field:
        # equality and repr see the config only)
        object.__setattr__(self, "tooth_learning", LearnerSettings(self.learn_teeth, self.tooth_memory,
                                                                   self.tooth_refit_cycles, self.tooth_speed_step))


class ConditionTables(NamedTuple):
    """What the cycles' grid and the condition settings fix once (core.monitor.checks.condition.condition_tables): the
    grid's first angle [rad] and size, the settings' angles they were made for (``key``: early_deg, late_margin_deg,
    late_max_deg, burn_half_deg), each cylinder's grid columns (z, 4) int64 and fractions towards the next column
    (z, 4) at ``early_deg`` and ``late`` before its firing TDC (the compression rise) and -+ ``burn_half_deg`` about
    it (the burn ratio), and the ring indicators' tables (None: the valve timing leaves no room for the windows)."""

    first_angle: float
    size: int
    key: tuple[float, ...]
    cols: np.ndarray
    frac: np.ndarray
    ring: RingTables | None

    def fits(self, grid: np.ndarray, key: tuple[float, ...]) -> bool:
        return grid.shape[0] == self.size and float(grid[0]) == self.first_angle and key == self.key


@dataclass(frozen=True)
class ConditionState:
    """The condition flags' window (core.monitor.checks.condition): cycles used, ``window`` (2, 3, z) the EWMA means
    (row 0) and variances about them (row 1) of each cylinder's deviation from its siblings in ln(compression rise),
    ln(pmax) and ln(indicated torque) (the properties name them), the EWMA of the reduced chi^2, the change detector
    (core.monitor.checks.change) and the cycles since the last operating-point change; burn_reference (z,) N m: each
    cylinder's EWMA indicated torque over its fully burned cycles (NaN before the first), and burn_cycles (z,) how
    many fed it: the reference a single cylinder's partial burn is judged against; tables: what the cycles' grid
    fixes of the pressure samples the flags read (core.monitor.checks.condition.condition_tables; None: made on the
    next cycle)."""

    count: int
    window: np.ndarray
    misfit: float
    detector: ChangeDetector | None
    since_op_change: int = 1 << 30
    burn_reference: np.ndarray | None = None
    burn_cycles: np.ndarray | None = None
    tables: ConditionTables | None = None

    @staticmethod
    def empty(n_cyl: int) -> ConditionState:
        return ConditionState(0, np.zeros((2, 3, n_cyl)), 1.0, None, burn_reference=np.full(n_cyl, np.nan),
                              burn_cycles=np.zeros(n_cyl, dtype=np.int64))

    @property
    def compression(self) -> np.ndarray:
        return self.window[0, 0]

    @property
    def compression_var(self) -> np.ndarray:
        return self.window[1, 0]

    @property
    def peak(self) -> np.ndarray:
        return self.window[0, 1]

    @property
    def peak_var(self) -> np.ndarray:
        return self.window[1, 1]

    @property
    def indicated(self) -> np.ndarray:
        return self.window[0, 2]

    @property
    def indicated_var(self) -> np.ndarray:
        return self.window[1, 2]


class PreviousCycle(NamedTuple):
    """What the next cycle's balance needs of the last analysed one: the ticks of its first and last tooth edges (it
    is the cycle just before only if the next one's first edge lies after its first and at or before its last:
    consecutive cycles share their boundary edges, core.types.Cycle; a stream index may be renumbered after a lost
    sync), pressure (z, n) [Pa], angle-averaged kinetic energy [J] (core.monitor.balance.mean_balance.cycle_energy),
    measured load [N m], indicated torque [N m] (the cylinders' work means over its own window, summed:
    Excitation.indicated_mean), coupling loss [N m] and load_late [N m] its load under the rising half of the
    balance's triangle (core.types.Cycle.load_late with the load's ripple work; not given: ``load``)."""

    start_tick: int
    end_tick: int
    pressure: np.ndarray
    energy: float
    load: float
    indicated: float
    coupling_loss: float
    load_late: float


@dataclass(frozen=True)
class TrigTables:
    """The cos/sin tables of the result's speed series, made once per run (core.monitor.report.cycle_report.trig_tables):
    table (2, m, n): cos and sin of 2 pi (h k mod n) / n for harmonics h = 1..m and samples k = 0..n-1
    (harmonic_series' convention: x_k = sum_h Re(X_h exp(i 2 pi h k / n)))."""

    table: np.ndarray

    def __post_init__(self):
        # shape (m harmonics, n samples): a plain attribute made once (not a field: equality and repr see the table
        # only), read by process_cycle each cycle without a call (design note 87)
        object.__setattr__(self, "shape", self.table.shape[1:])


class GridGeometry(NamedTuple):
    """What the cycles' crank-angle grid fixes once (core.monitor.balance.mean_balance.grid_geometry): the grid's first
    angle [rad] and size (a cycle on another grid makes it anew), every cylinder's piston displacement on it
    positions (z, n) [m], J(theta = 2 pi) [kg m^2] and each piston's x'' (z, n) [m/rad^2] (the indicated work's
    sensitivity to a TDC error, core.monitor.balance.mean_balance.indicated_tdc_sensitivity); the transient balance's
    window starts (core.model.indicated.window_starts): window_starts (1, z) of each cylinder's own firing window in
    [previous | current], alone_starts (1, z) of the cycle's own closed loop, its triangle's weights
    triangle_previous, triangle_current (z, n) [m^2/rad] (core.monitor.balance.mean_balance.triangle_weights) and
    each sample's share of a closed trapezoid's dx, central_dx (z, n) [m] (half the positions' central difference:
    core.monitor.balance.mean_balance.balance_sums) (None: made by the balance)."""

    first_angle: float
    size: int
    positions: np.ndarray
    inertia_mid: float
    piston_acceleration: np.ndarray
    window_starts: np.ndarray | None = None
    alone_starts: np.ndarray | None = None
    triangle_previous: np.ndarray | None = None
    triangle_current: np.ndarray | None = None
    central_dx: np.ndarray | None = None

    def fits(self, grid: np.ndarray) -> bool:
        return grid.shape[0] == self.size and float(grid[0]) == self.first_angle


class EnergyWeights(NamedTuple):
    """What a cycle's angle-averaged kinetic energy weighs its tooth intervals' 1 / dt^2 by, fixed by the edges'
    nominal angles (core.monitor.balance.mean_balance.energy_weights): the cycle's edge angles (m,) [rad] they
    were made for and the weights (m - 1,) [kg m^2 rad^2]."""

    tooth_angle: np.ndarray
    weights: np.ndarray

    def fits(self, cycle: Cycle) -> bool:
        return same_edges(self.tooth_angle, cycle.tooth_angle)


def same_edges(mine: np.ndarray, theirs: np.ndarray) -> bool:
    """np.array_equal's answer (shapes, then every value; NaN unequal) without its asarray and wrapper calls: asked
    every cycle (~0.6 % of a k9k cycle through array_equal, design note 46)."""
    return mine.shape == theirs.shape and bool((mine == theirs).all())


@dataclass(frozen=True)
class MonitorState:
    """Everything carried from one cycle to the next (scipy ``zi`` style: in and out of ``process_cycle``)."""

    layout: ParameterLayout
    n_harmonics: int
    n_nuisance: int
    accumulator: Accumulator
    stats: ResidualStats
    params: np.ndarray  # [friction scales, tooth nuisances], the smoothed estimate
    op: OperatingPoint | None
    relative_motion: np.ndarray | None
    static: np.ndarray | None
    teeth: ToothLearner
    balance_mean: float
    indicated_mean: np.ndarray
    cycles: int
    prior: PriorNormal  # normal equations of the fixed priors (core.monitor.identify.parameters)
    lower: np.ndarray  # lower bounds of the parameters: 0 for the friction scales, -inf (free) for the nuisances
    report_tables: TrigTables  # cos/sin tables of the result's speed series (core.monitor.report.cycle_report.trig_tables)
    prev_omega: float = float("nan")
    drift_var: float = 0.0
    tooth_patterns: ToothPatterns | None = None  # the in-band tooth-error patterns at the edges (core.monitor.teeth.tooth_fit)
    sensor: SensorHealthState | None = None  # sensor-health estimates and corrections (core.monitor.checks.sensor_health)
    condition: ConditionState | None = None  # the condition flags' window and change detector (core.monitor.checks.condition)
    previous: PreviousCycle | None = None  # the last analysed cycle: centred windows and the kinetic-energy term
    grid_geometry: GridGeometry | None = None  # the crank-angle grid's piston positions and J(2 pi)
    energy_weights: EnergyWeights | None = None  # the cycle energy's weights at the edges' angles
    wheel2: SecondWheelState | None = None  # the second wheel's tooth learner (core.monitor.teeth.tooth_fit)
    motion: ThrowMotion | None = None  # each throw's angle against the wheel in the newest cycle (the stages read it)

    def previous_of(self, first_tick: int) -> PreviousCycle | None:
        """``previous`` if it is the cycle just before one whose first tooth edge is at ``first_tick``, else None."""
        p = self.previous
        return p if p is not None and p.start_tick < first_tick <= p.end_tick else None
