"""The service contract's JSON shapes as pydantic models (OpenAPI at /openapi.json). Units in the field names:
bar, nm (N m), rpm, deg (crank angle), kw, s; cylinders 1-based. A figure that is not known is null, never a number.

Models allow extra keys: a helper may add fields to the contract, never rename or drop one.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

Status = Literal["measured", "share", "prior", "unresolved", "withheld"]
Calibrated = Literal["uncalibrated", "commissioned"]
CALIBRATION_WORDS = ("core/model/calibration.py: 'uncalibrated' = the sigma assumes a typical installation's TDC, "
                     "pressure gain and J; 'commissioned' = what frictionwatch commission measured")
CALIBRATION_SIGMA_WORDS = ("the part of the sigma the calibration's remaining uncertainty adds [N m]; the same in every "
                           "cycle, so it cancels in a change since commissioning")


class _Open(BaseModel):
    model_config = ConfigDict(extra="allow")


class HealthEngine(_Open):
    engine_id: str
    running: bool
    last_cycle_age_s: float | None = Field(description="seconds since the newest result; null before the first")
    behind: bool = Field(False, description="a real-time source's data wait longer than lag_degraded_s: 'degraded'")
    queued_cycles: float | None = Field(None, description="cycles of data queued for the monitor (at the newest "
                                                          "result's speed; null before the first)")
    queued_s: float = Field(0.0, description="acquisition seconds queued for the monitor")
    behind_s: float = Field(0.0, description="wall seconds the oldest queued data have waited")
    dropped_records: int = Field(0, description="records dropped to keep the queue bounded (the oldest go)")
    dropped_s: float = Field(0.0, description="acquisition seconds those records covered")
    dropped_cycles: float | None = Field(None, description="cycles those seconds hold at the newest speed")
    realtime: bool = Field(False, description="a source runs at the engine's pace (a fast replay only reads ahead)")
    last_drop_age_s: float | None = Field(None, description="seconds since the queue last dropped records (degraded "
                                                            "for 30 s after a drop); null: never")
    holding: bool = Field(False, description="a board's input is held beyond max_queue_s while the warm-up runs, "
                                             "until the monitor has caught up (serve --hold-mb)")
    held_s: float = Field(0.0, description="the most acquisition seconds the hold kept queued at once (0: none)")
    held_bytes: int = Field(0, description="... and the bytes they held (an estimate: arrays' data and records)")
    held_records: int = Field(0, description="... and the records")
    store_waiting_cycles: int = Field(0, description="cycles kept for the store while it is down, written when it is "
                                                     "back ('degraded' while any wait)")
    store_lost_cycles: int = Field(0, description="cycles the store never got (its backlog full, or a write that "
                                                  "failed twice)")
    warming_up: bool = Field(False, description="the warm-up compiles the engine's kernels before its first record "
                                                "(a replay starts after it; a serial or CAN board's input is queued)")
    startup: str | None = Field(None, description="while warming up: 'compiling kernels: k of N'; then, while the "
                                                  "monitor catches up on a board's held input: 'catching up on ...'")
    paced_by_listener: str | None = Field(None, description="a replay faster than real time waiting now for this "
                                                        "listener's full queue (e.g. 'store'): it runs at that "
                                                        "listener's pace and loses nothing; null: not waiting")


class Health(_Open):
    status: Literal["ok", "degraded", "starting"] = Field(description="starting: an engine's warm-up compiles its "
                                                                      "kernels (nothing is analysed or lost yet), or "
                                                                      "the monitor catches up on what a board gave "
                                                                      "meanwhile (held, nothing dropped)")
    uptime_s: float
    lag_degraded_s: float = Field(2.0, description="an engine is 'degraded' when its data wait longer than this")
    fleet: bool = Field(False, description="GET /api/v1/fleet answers: this service keeps a store")
    engines: list[HealthEngine]


class StartupEngine(_Open):
    engine_id: str
    state: Literal["compiling", "starting", "running"] = Field(
        description="running: it has analysed a cycle; compiling: not yet, and this process is compiling numba "
                    "kernels (a fresh install: 1-2 min, first run only); starting: not yet, kernels from the cache")
    cycles_ok: int
    warm_up: str | None = Field(None, description="while serve's warm-up compiles the engine's kernels before its "
                                                  "first record: 'compiling kernels: k of N' (its steps); else null")


class Startup(_Open):
    """What the service does before each engine's first cycle (service/startup.py); the data routes answer 503
    until then."""

    state: Literal["compiling", "starting", "running"] = Field(description="the least advanced engine's state")
    message: str | None = Field(description="the state in words for a person; null when running")
    kernels_compiled: int = Field(description="numba compilations in this process so far (0: all from the cache)")
    elapsed_s: float = Field(description="seconds since the process started")
    engines: list[StartupEngine]


class EngineInfo(_Open):
    engine_id: str
    engine_name: str
    n_cylinders: int
    sources: list[str]
    cycles_ok: int
    skipped: dict[str, int]
    restarts: dict[str, int] = Field(default_factory=dict, description="stream restarts by reason, where the cycle "
                                     "assembler starts again (loop_restart: a looped replay's seam; dropped_while_"
                                     "behind: where the ingest queue dropped data, counted in /health's dropped_*): "
                                     "not lost cycles")
    rpm_latest: float | None
    listener_drops: dict[str, int] = Field(description="events each fan-out listener lost to a full queue")
    listener_left: dict[str, int] = Field(default_factory=dict, description="events a stop left undelivered, per "
                                                                        "listener")
    listener_waited_s: dict[str, float] = Field(default_factory=dict, description="seconds a replay faster than real "
                                                "time waited for each listener's full queue (ran at its pace)")
    backlog: dict | None = Field(None, description="the monitor's lag as in /health's engine rows (queued_cycles, "
                                                   "behind_s, dropped_records, behind, ...)")
    store: dict[str, int] | None = Field(None, description="what the store listener wrote (cycles_written, "
                                         "cycles_written_late: kept while the store was down), lost (lost_cycles, "
                                         "lost_batches), and holds now (backlog_cycles); null without a store")


class FleetFigure(_Open):
    fmep_bar: float | None = Field(description="the engine's smoothed FMEP at its newest stored cycle; null unless "
                                               "measured")
    fmep_sigma_bar: float | None
    status: str | None = Field(description="measured, prior, unresolved, withheld; null: stored without a figure")
    reason: str | None


class FleetEngine(_Open):
    engine_id: str
    writer: str | None = Field(description="host:pid:token of the process that writes this engine; null: none")
    writer_live: bool = Field(description="the writer's heartbeat younger than the lease timeout (60 s)")
    heartbeat_age_s: float | None
    run_id: int | None
    last_cycle: int | None = Field(description="the newest cycle committed to the store")
    t_start_s: float | None = Field(description="its acquisition time [s]")
    last_cycle_age_s: float | None = Field(description="seconds since it was committed (the database's clock)")
    engine: FleetFigure
    active_alerts: int
    acknowledged_alerts: int


class CycleSummary(_Open):
    engine_id: str
    cycle_index: int
    t_start_s: float | None
    rpm_mean: float | None
    load_torque_nm: float | None
    load_power_kw: float | None
    imep_bar: list[float | None]
    pmax_bar: list[float | None]
    friction_balance_nm: float | None
    flags: list[str]
    missing_before: dict | None = Field(default=None, description=(
        "a stored cycle only (the store's `extra`), the first after a hole the service dropped while its analysis "
        "was behind: the hole (reason, first_cycle..last_cycle the indices not analysed, cycles, dropped_cycles the "
        "crank cycles its flywheel edges held, dropped_s, dropped_records); absent otherwise"))


MEASURED_ONLY = "a measurement only: null where the status is not 'measured' (a share's value is under share_*)"
SHARE_ONLY = ("the cylinder's share of the engine's measured friction in proportion to its indicated work (paper 000 "
              "Eq. 6), where the status is 'share': a rule applied to the measured total, not a measurement of this "
              "cylinder; null otherwise")


class CylinderLoss(_Open):
    cylinder: int
    fmep_bar: float | None = Field(description=MEASURED_ONLY)
    fmep_sigma_bar: float | None = Field(description=MEASURED_ONLY)
    friction_torque_mean_nm: float | None = Field(description=MEASURED_ONLY)
    friction_torque_sigma_nm: float | None = Field(description=MEASURED_ONLY)
    share_fmep_bar: float | None = Field(default=None, description=SHARE_ONLY)
    share_fmep_sigma_bar: float | None = Field(default=None, description=SHARE_ONLY)
    share_friction_torque_mean_nm: float | None = Field(default=None, description=SHARE_ONLY)
    share_friction_torque_sigma_nm: float | None = Field(default=None, description=SHARE_ONLY)
    coefficients: dict[str, float | None]
    coefficient_sigmas: dict[str, float | None]
    data_weight: float | None
    status: Status = Field(description="core/monitor/report/figure_status.py: only 'measured' is a measurement")
    reason: str | None
    calibration: Calibrated = Field(description=CALIBRATION_WORDS)
    calibration_sigma_nm: float | None = Field(description=CALIBRATION_SIGMA_WORDS)
    flags: list[str]


class LossWindow(_Open):
    first_cycle: int | None
    last_cycle: int
    cycles: float | None = Field(description="cycles behind the figures (effective cycles for the smoothed estimate)")
    cycles_left_out: int | None = Field(default=None, description=(
        "a window mean only: cycles of the window without a previous cycle (a log's first, each loop seam of a "
        "replay, a stream restart), which have no estimate of their own and are left out of the means; 'cycles' "
        "does not count them"))
    left_out: str | None = Field(default=None, description="a window mean only: what was left out, in words "
                                                           "('1 cycle without a previous cycle left out'); null "
                                                           "when nothing was")
    cycles_missing: int | None = Field(default=None, description=(
        "a window mean only: cycle indices within first_cycle..last_cycle with no result (skipped by the assembly "
        "or the monitor, or dropped while the analysis was behind); the window spans them, its figures do not"))
    cycles_dropped: int | None = Field(default=None, description=(
        "a window mean only: of cycles_missing, those in holes the service dropped while its analysis was behind"))
    missing: str | None = Field(default=None, description="a window mean only: the missing cycles in words; null "
                                                          "when none are")


class EngineLoss(_Open):
    fmep_bar: float | None
    fmep_sigma_bar: float | None
    calibration: Calibrated = Field(description=CALIBRATION_WORDS)
    calibration_sigma_nm: float | None = Field(description=CALIBRATION_SIGMA_WORDS)


class Losses(_Open):
    engine_id: str
    cycle_index: int
    window: LossWindow
    engine: EngineLoss
    cylinders: list[CylinderLoss]


class FrictionTorque(_Open):
    cycle_index: int
    crank_angle_deg: list[float]
    friction_torque_nm: list[float | None]
    friction_torque_cyl_nm: list[list[float | None]]


class SpeedHistory(_Open):
    cycle_index: list[int]
    rpm_mean: list[float | None]


class Speed(_Open):
    cycle_index: int
    crank_angle_deg: list[float]
    speed_measured_rpm: list[float | None]
    speed_model_rpm: list[float | None]
    history: SpeedHistory


class TdcCylinder(_Open):
    cylinder: int
    offset_deg: float | None = Field(description="this cylinder's TDC found from its pressure, against the TDC the "
                                                 "model states after its corrections [deg crank]; + = the true TDC "
                                                 "is later; null: the fit failed in this window")
    sigma_deg: float | None = Field(description="1 sigma of offset_deg [deg]")
    method: str | None = Field(description="the fit: rohr-compression-expansion (fired) or "
                                           "rohr-motored-heat-loss-shaping (motored)")


class TdcWatch(_Open):
    """The TDC watch (core/monitor/calibration/tdc_watch.py, on by default): every window_cycles cycles each
    cylinder's TDC is found from its own pressure and judged against the model's calibration."""

    window_cycles: int = Field(description="cycles per window (100)")
    cycles_gathered: int = Field(description="cycles gathered towards the next window")
    window_last_cycle: int | None = Field(description="the cycle that closed the newest window; null before the "
                                                      "first window (after window_cycles cycles)")
    wheel_offset_deg: float | None = Field(description="the wheel's TDC offset: the median of the cylinders' [deg]; "
                                                       "null before the first window")
    wheel_sigma_deg: float | None = Field(description="1 sigma of wheel_offset_deg: the median of the cylinders' "
                                                      "sigmas [deg]")
    flags: list[str] = Field(description="flags the newest window raised: sensor_tdc_offset (the wheel beyond what "
                                         "the calibration allows: every figure withheld), sensor_tdc_offset_cyl<k> "
                                         "(cylinder k moved against its siblings: its figures withheld)")
    cylinders: list[TdcCylinder] = Field(description="one per cylinder; empty before the first window")


class CalibrationState(_Open):
    """The engine model's calibration section (core/model/calibration.py) every friction sigma carries."""

    status: Calibrated = Field(description=CALIBRATION_WORDS)
    source: str = Field(description="where the numbers come from, in words")
    tdc_wheel_sigma_deg: float = Field(description="1 sigma of the wheel's TDC, common to every cylinder [deg]")
    tdc_cylinder_sigma_deg: float = Field(description="1 sigma of each cylinder's own TDC beyond the wheel's [deg] "
                                                      "(the cylinders' rms)")
    gain_sigma_pct: float = Field(description="1 sigma of each pressure channel's gain [%] (the channels' rms)")
    tdc_cylinder_sigmas_deg: list[float] = Field(description="each cylinder's own TDC 1 sigma [deg], what its "
                                                             "friction sigma carries (commissioning writes one per "
                                                             "cylinder; else tdc_cylinder_sigma_deg for each)")
    gain_sigmas_pct: list[float] = Field(description="each channel's gain 1 sigma [%], what its cylinder's friction "
                                                     "sigma carries: a channel commissioning corrected holds its whole "
                                                     "correction (a cylinder's own charge reads alike); else "
                                                     "gain_sigma_pct for each")
    gain_common_sigma_pct: float = Field(description="1 sigma of the gain common to every channel [%]")
    inertia_sigma_pct: float = Field(description="1 sigma of the inertia J [%]")
    load_torque_sigma_pct: float = Field(description="1 sigma of the load read as a shaft torque [%]")
    load_power_sigma_pct: float = Field(description="1 sigma of the load read as electrical power over the generator's "
                                                    "efficiency and the speed [%] (a genset without a torque reading)")
    generator_efficiency: float = Field(description="the generator efficiency the electrical power is divided by "
                                                    "(1.0: not stated, its losses then inside the load sigma)")


class SensorHealth(_Open):
    """What checks the sensors: the TDC watch and the calibration always; the speed-based stage where switched on."""

    cycle_index: int = Field(description="the newest cycle, whose flags these are")
    enabled: bool = Field(description="the speed-based sensor-health stage (core/monitor/checks/sensor_health.py) is on: "
                                      "opt-in, `serve --sensor-health`; off by default because where the model is "
                                      "not the engine its TDC is not reliable (docs/design-notes.md item 13)")
    cylinders: list[dict] = Field(description="the speed-based stage's per-cylinder TDC offset, pressure gain and "
                                              "pegging with 1 sigma and the corrections in use; empty when it is off")
    flags: list[str] = Field(description="every sensor_* flag of the newest cycle, from either check; each "
                                         "withholds the figures it touches")
    wheel_tdc_offset_deg: float | None = Field(description="the speed-based stage's wheel TDC offset; null when off")
    wheel_tdc_offset_sigma_deg: float | None
    friction_sigma_nm: float | None = Field(description="what the speed-based stage's remaining TDC and gain "
                                                        "uncertainty adds to the engine friction's 1 sigma")
    speed_based_flags: list[str] = Field(description="the flags the speed-based stage raised; empty when off")
    tdc_watch: TdcWatch
    calibration: CalibrationState


class Alert(_Open):
    """One alert. GET .../alerts returns a bounded list of them: the newest ``limit`` (default 100, at most 1000),
    oldest first; the X-Total-Count header says how many the service holds (the store keeps every one)."""

    alert_id: int
    engine_id: str
    cylinder: int | None
    kind: str
    severity: Literal["info", "warning", "alarm"]
    state: Literal["active", "acknowledged", "cleared"]
    raised_cycle: int
    raised_at_s: float
    cleared_cycle: int | None
    acknowledged_by: str | None
    message: str
    evidence: dict


class RingCondition(_Open):
    """One cylinder's ring condition (core.monitor.checks.ring_condition): ``ring_condition`` in units of a worn ring
    at the alerts' floor (1.0: a leak effect of AlertConfig.leak_floor, or a friction excess of 10 %) with its 1
    sigma, under ``ring_condition_reference`` (since_baseline: the change since commissioning; against_siblings: the
    deviation from the other cylinders now, for a fault present from the start); the evidence under it, each None
    where it has no value: the leak effect [polytropic-exponent units] and the measured friction excess (relative);
    the TDC error that reads as the same leak against the siblings."""

    cylinder: int
    ring_condition: float | None
    ring_condition_sigma: float | None
    ring_condition_reference: Literal["since_baseline", "against_siblings"] | None
    ring_condition_since_baseline: float | None
    ring_condition_since_baseline_sigma: float | None
    ring_condition_against_siblings: float | None
    ring_condition_against_siblings_sigma: float | None
    leak_effect_change: float | None
    leak_effect_change_sigma: float | None
    leak_effect_against_siblings: float | None
    leak_effect_against_siblings_sigma: float | None
    friction_excess_change: float | None
    friction_excess_against_siblings: float | None
    tdc_equivalent_deg: float | None = Field(None, description="the TDC error of this cylinder [deg] that would read "
                                             "as the leak effect against the siblings: the pressure indicators cannot "
                                             "tell the two apart, and a TDC found from the pressure (commissioning's "
                                             "too) reads a leak as TDC: only a TDC measured apart from it tells them "
                                             "apart (design note 32)")


class BaselineResult(_Open):
    ok: bool
    engine_id: str
    baseline: dict | None


class Acknowledge(BaseModel):
    model_config = ConfigDict(extra="forbid")
    by: str = Field(default="operator", min_length=1, max_length=80, pattern=r"^[\w .@-]+$")


BASELINE_PATTERN = r"^(default|rigid|without:[a-z_]{1,40}(,[a-z_]{1,40}){0,15})$"


class DiscrepancyRequest(BaseModel):
    """A discrepancy run on the engine's recorded window (service/discrepancy_jobs.py)."""

    model_config = ConfigDict(extra="forbid")
    cycles: int = Field(default=120, ge=28, le=2000,
                        description="newest cycles to analyse (the workflow needs 28: 12 to settle, 8 to train, "
                                    "8 held out); at most what the engine's record window holds")
    baseline: str = Field(default="default", pattern=BASELINE_PATTERN,
                          description="default effects of the engine's model: default | rigid | without:NAME[,NAME]")
    max_steps: int = Field(default=3, ge=0, le=5, description="effects to add at most")


class DiscrepancyJob(_Open):
    job_id: str
    engine_id: str
    state: Literal["running", "done", "failed"]
    reason: str | None = Field(description="why the job failed, one line; null otherwise")
    cycles_requested: int
    baseline: str
    max_steps: int
    records: int = Field(description="raw records of the window handed to the workflow")
    elapsed_s: float
    report: dict | None = Field(description="the workflow's JSON report when done (found, gap_before, gap_after, "
                                            "metric, verdict, localisation, ...), as `frictionwatch discrepancy "
                                            "--json` prints it; null otherwise")


class ErrorBody(BaseModel):
    detail: str
