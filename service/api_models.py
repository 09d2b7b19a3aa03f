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


class Health(_Open):
    status: Literal["ok", "degraded"]
    uptime_s: float
    engines: list[HealthEngine]


class EngineInfo(_Open):
    engine_id: str
    engine_name: str
    n_cylinders: int
    sources: list[str]
    cycles_ok: int
    skipped: dict[str, int]
    rpm_latest: float | None
    listener_drops: dict[str, int] = Field(description="events each fan-out listener lost to a full queue")


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


class CylinderLoss(_Open):
    cylinder: int
    fmep_bar: float | None
    fmep_sigma_bar: float | None
    friction_torque_mean_nm: float | None
    friction_torque_sigma_nm: float | None
    coefficients: dict[str, float | None]
    coefficient_sigmas: dict[str, float | None]
    data_weight: float | None
    status: Status = Field(description="core/monitor/figure_status.py: only 'measured' is a measurement")
    reason: str | None
    calibration: Calibrated = Field(description=CALIBRATION_WORDS)
    calibration_sigma_nm: float | None = Field(description=CALIBRATION_SIGMA_WORDS)
    flags: list[str]


class LossWindow(_Open):
    first_cycle: int | None
    last_cycle: int
    cycles: float | None = Field(description="cycles behind the figures (effective cycles for the smoothed estimate)")


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


class SensorHealth(_Open):
    enabled: bool
    cylinders: list[dict]
    flags: list[str]


class Alert(_Open):
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
