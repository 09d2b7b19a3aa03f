"""What the discrepancy workflow found (core.discrepancy.workflow.discover): its options, each added step and the
whole outcome (named, ambiguous, unexplained or nothing), with the signature of what remains and the JSON the CLI,
the API and the report read. Records only: the loop that fills them is workflow.py."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from frictionwatch.core.discrepancy.features import SIGNIFICANT, beyond_healthy_gap, beyond_null
from frictionwatch.core.discrepancy.fit import Trial
from frictionwatch.core.discrepancy.residuals import GROUP_SPEED_STEP
from frictionwatch.core.discrepancy.words import verdict
from frictionwatch.core.model.engine_model import EngineModel
from frictionwatch.core.monitor.state import MonitorConfig

METRIC = ("held-out coherent residual: sqrt(sum over features of (cycle mean^2 - its noise variance) / per-cycle "
          "noise variance); features: Re and Im of the flywheel-speed residual at every engine order (0.5 steps) "
          "and the mean torque-balance residual; per-cycle noise from the baseline's training cycles")


@dataclass(frozen=True)
class Options:
    max_steps: int = 3
    warmup: int = 12
    fit_cycles: int = 24
    # on a log of several operating points the fits run on the whole training half, not its first fit_cycles: those
    # hold the first point's block and the first cycles after the first step (k9k 3000/0.9 <-> 1800/0.6 seed 17, a
    # cam-order friction: 11 cycles at 3000 rpm and 6 at 1800, the speed still drifting after its step; the cam
    # stand-in fitted there at amplitude 1.48 against the truth's 0.8 lost the held-out test to a worn ring, which
    # was named; fitted on the training half, 0.95, held-out floored chi^2 246 against the ring's 485; design note
    # 155). False: the first fit_cycles, as before
    fit_all_points: bool = True
    refine: int = 3
    # distinct shapes held out per step (Candidate.shape; choice.to_confirm): the 24-cycle window's speed residual
    # wanders between stretches of the log by more than the held-out noise (k9k 1800 rpm seed 2, nothing but a
    # constant friction hidden: coherent speed chi^2 835, 506, 185, 479 over four stretches), so its ranking can put
    # the shape that explains the held-out cycles best fourth (there: a worn ring, window 1601, held out 321; the
    # constant, window 1898, held out 172); each further shape is one refinement and one whole-log run. Chosen on
    # that log (4: where the constant ranked); validated on the held-out matrices of design note 39
    confirm: int = 4
    # where nothing in the held-out residual is beyond the null (features.beyond_null): the width before note 39;
    # chosen after seeing deutz 3000 rpm seed 2 (the loop below), validated on k9k 3000 rpm and maruti 4000 rpm seed 2
    confirm_within_null: int = 2
    min_delta_chi2: float = 40.0
    min_reduction: float = 0.15
    # on a quiet residual (choice.quiet_residual) a step must also pass the held-out test with the model-error floor
    # allowed for (choice.within_model_error; design note 61); False: the plain test alone, as before that note
    floored_when_quiet: bool = True
    # where the floored test applies: wherever the residual is inside the null (choice.within_null: nothing beyond
    # the floors, the speed gap within GAP_NULL; design note 155), False: only where it is quiet (note 61's gate,
    # the speed gap within the typical healthy one), as before
    floored_within_null: bool = True
    monitor_config: MonitorConfig | None = None


@dataclass(frozen=True)
class Step:
    """One added effect: the trial that named it (None: the pressure named it, ``readings`` say how), the effect
    (fitted values and sigma), held-out gaps and coherent chi^2 before and after, the runner-up and the localisation of
    the residual it explained."""

    trial: Trial | None
    effect: object
    gap_before: float
    gap_after: float
    chi2_before: float
    chi2_after: float
    runner_up: str | None
    before: dict
    after: dict
    also: tuple = ()  # the further effects a toggle of several default effects added at once
    readings: tuple = ()  # a pressure step's: what the pressure showed of each effect, in words (trial None)
    channel: str = ""  # where it was named, when not by a speed trial or the pressure ("torque balance across points")
    # a speed step's held-out chi^2 fall with the model-error floor allowed for (choice.chi2_floored) and whether the
    # residual it explained was quiet (choice.quiet_residual): what choice.within_model_error judged (note 61)
    floored_fall: float | None = None
    quiet: bool | None = None
    within_null: bool | None = None  # and whether it lay inside the null (choice.within_null, note 155)

    @property
    def effects(self) -> tuple:
        return (self.effect, *self.also)

    @property
    def label(self) -> str:
        """What was added, as candidates are labelled ('ring_wear[cyl 4]'; a pressure step's effects, each)."""
        if self.trial is not None:
            return self.trial.candidate.label
        return ", ".join(e.name if e.values.get("cylinder") is None else f"{e.name}[cyl {e.values['cylinder']}]"
                         for e in self.effects)


@dataclass
class Discovery:
    baseline: EngineModel
    model: EngineModel
    steps: list[Step]
    gap_before: float
    gap_after: float
    localisation: dict  # the baseline's residual on the held-out cycles
    final: dict  # the final model's
    curves: list[tuple[str, np.ndarray, np.ndarray]] = field(default_factory=list)  # (label, angles, mean residual)
    rejected: dict = field(default_factory=dict)  # considered and not significant: label -> held-out gap
    evaluations: int = 0
    refused: list = field(default_factory=list)  # significant but refused: {"candidate", "reason"}
    ambiguous: dict | None = None  # two explanations within the noise: {"candidates", "separated_by"}
    dropped: dict = field(default_factory=dict)  # fits that cannot be their effect's physics: label -> why
    step_limit_reached: bool = False
    # the explanations a step found equally good where nothing was beyond the null (features.beyond_null): no
    # discrepancy, said in the verdict and never reported as an ambiguity (design note 39)
    within_null_fits: list = field(default_factory=list)
    # the friction laws fitted to the balance point by point (laws.py; a log at several operating points): each fit
    across_points: list = field(default_factory=list)
    held: list = field(default_factory=list)  # the TDC offsets the pressure named: their sigma enters later fits'
    pair_not_taken: str = ""  # why a TDC the pressure read beside a rival was not added (pair.tdc_and_friction)
    # the pressure sensors the monitor flags with a fault no candidate describes (sensor_faults.undescribed_faults):
    # where there are any, nothing is named (an ambiguity with them); said in the verdict either way
    sensor_faults: list = field(default_factory=list)
    # the pressure channels the monitor stood the siblings' pressure in for (sensor_faults.stood_in_channels): said
    stood_in: list = field(default_factory=list)

    @property
    def remainder(self) -> dict | None:
        """The signature of what the final model leaves coherent on the held-out cycles (None: nothing significant)."""
        f = self.final
        if not f or not (beyond_null(f) or beyond_healthy_gap(f)):
            return None
        top = sorted(f["cylinders"], key=lambda c: -c["relative"])[:2]
        # nothing beyond the null but a speed gap far beyond a healthy log's (features.healthy_gap): its orders, said
        # as inside the model-error floor (the model's own error there is an explanation too)
        floor = None if beyond_null(f) else f["healthy_gap"]
        return {"engine_orders": f["significant_orders"] if floor is None else floor["orders"],
                "half_order_share": f["half_order_share"],
                "balance_nm": f["balance"]["mean_nm"] if f["balance"]["significant"] else None,
                "balance_sigma_nm": f["balance"].get("sigma_nm"), "balance_floor_nm": f["balance"].get("floor_nm"),
                "peak_deg": f["angle"]["peak_deg"], "cylinder_windows": [c["cylinder"] for c in top],
                "channels": f["channels"], "friction": f.get("friction"), "load_nm": f.get("load_nm"),
                "inside_floor": floor}

    @property
    def within_floor(self) -> list[float]:
        """Engine orders whose held-out coherent speed residual is beyond its sigmas but inside the model-error
        floor: what the model leaves that the null attributes to the model itself (said, not named)."""
        f = self.final
        if not f:
            return []
        return [o["order"] for o in f["orders"]
                if o["amplitude_rpm"] > SIGNIFICANT * o["sigma_rpm"] and not o["significant"]]

    @property
    def within_pattern(self) -> list[float]:
        """Engine orders whose held-out coherent speed residual is beyond its noise's sigmas and above the model-error
        floor but within what the wheel's in-band tooth pattern, still being learnt, can put there (the order
        table's ``pattern_sigma_rpm``, design note 118): said, not named."""
        f = self.final
        if not f:
            return []
        return [o["order"] for o in f["orders"] if not o["significant"] and o["amplitude_rpm"] > o["floor_rpm"]
                and o["amplitude_rpm"] > SIGNIFICANT * o.get("noise_sigma_rpm", o["sigma_rpm"])]

    @property
    def one_operating_point(self) -> bool:
        """Whether the held-out cycles ran at one operating point (features.localise ``operating_points``, the
        groups of residuals.operating_groups). Before design note 58 this read features.trends, which a steady log's
        cycle-to-cycle scatter always gives a slope: it was False on every matrix log, and the verdict never said
        that one point cannot tell a friction law."""
        return (self.localisation or {}).get("operating_points", 1) == 1

    @property
    def one_speed(self) -> bool:
        """Whether the held-out cycles ran at several operating points of one speed (their mean speeds within
        residuals.GROUP_SPEED_STEP of each other: load steps only, e.g. a genset on the grid)."""
        points = ((self.localisation or {}).get("balance") or {}).get("points") or []
        rpm = [p["rpm"] for p in points]
        return len(rpm) > 1 and max(rpm) - min(rpm) <= GROUP_SPEED_STEP * float(np.mean(rpm))

    @property
    def outcome(self) -> str:
        if self.steps:
            return "named"
        if self.ambiguous:
            return "ambiguous"
        return "unexplained" if self.remainder is not None else "nothing"

    def verdict(self) -> str:
        """One sentence for the top of the report (words.verdict)."""
        return verdict(self)

    def to_json(self) -> dict:
        found = []
        for s, e in [(st, ef) for st in self.steps for ef in st.effects]:
            params = {k: v for k, v in e.values.items() if k != "cylinder"}
            found.append({"effect": e.name, "cylinder": e.values.get("cylinder"), "parameters": params,
                          "sigma": dict(e.sigma),
                          "evidence": {"gap_before": s.gap_before, "gap_after": s.gap_after,
                                       "delta_chi2_heldout": s.chi2_before - s.chi2_after,
                                       "channel": s.channel or ("speed" if s.trial is not None else "pressure"),
                                       "pressure_reading": s.readings[s.effects.index(e)] if s.readings else None,
                                       "train_cost_reduction": s.trial.gain if s.trial is not None else None,
                                       "runner_up": s.runner_up,
                                       "delta_chi2_heldout_floored": s.floored_fall, "quiet_before": s.quiet,
                                       "within_null_before": s.within_null,
                                       "significant_orders_before": s.before["significant_orders"],
                                       "balance_before_nm": s.before["balance"]["mean_nm"],
                                       "balance_after_nm": s.after["balance"]["mean_nm"],
                                       # what adding it does to the friction the balance measures (analyze's)
                                       "measured_friction_before": s.before.get("friction"),
                                       "measured_friction_after": s.after.get("friction")}})
        return {"found": found, "gap_before": self.gap_before, "gap_after": self.gap_after, "metric": METRIC,
                "outcome": self.outcome, "verdict": self.verdict(), "remainder": self.remainder,
                "within_model_error_floor": self.within_floor,
                "ambiguous": self.ambiguous, "within_null_fits": self.within_null_fits,
                "refused": self.refused, "step_limit_reached": self.step_limit_reached,
                "one_operating_point": self.one_operating_point,
                "localisation": self.localisation, "final": self.final, "not_significant": self.rejected,
                "not_physical": self.dropped, "pair_not_taken": self.pair_not_taken,
                "laws_across_points": self.across_points, "sensor_faults": self.sensor_faults,
                "stood_in_channels": self.stood_in,
                "monitor_runs": self.evaluations}
