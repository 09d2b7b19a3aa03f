"""How well the installation's sensors are known: the model's calibration section (issue 25 item 2).

Every friction figure rests on the pressure's crank-angle reference (TDC), the pressure sensors' gain, the
inertia the kinetic-energy term uses and the load reading. A TDC error moves a cylinder's indicated work by
dW/dDelta = -A ∮ p x'' dtheta and a gain error by W itself; the mean balance passes both into friction whole (0.1 deg
of TDC is 6-7 % of the genset-v20's friction, 1 % of gain 8-12 %: docs/information.md), and the load's error too
(friction = indicated - load - ...: on genset-v20 at 75 % load the load is ~9x the friction, so 1 % of load is ~9 %
of friction). The monitor adds what the calibration leaves
uncertain to every friction sigma through those sensitivities (core.monitor.identify.estimate.calibration_variance), so a
figure never claims to know more than its sensors allow.

A model without a calibration section is ``uncalibrated``: its sigmas assume a typical installation whose TDC was set
statically and whose sensors carry their data-sheet sensitivity, the values of ``Calibration()`` below. ``frictionwatch
commission`` replaces them with what it measured (status ``commissioned``) and writes the corrections themselves as
the model's sensor effects (tdc_offset, pressure_gain, pressure_offset), which core.model.view applies.

In the model's TOML (core.model.engine_model), every key optional (the defaults below):

    [model.calibration]
    status = "commissioned"
    tdc_wheel_sigma_deg = 0.05       # the wheel's TDC: an error common to every cylinder
    tdc_cylinder_sigma_deg = 0.05    # each cylinder's own TDC beyond the wheel's, independent between cylinders
    gain_sigma = 0.005               # each pressure channel's relative gain, independent between cylinders
    gain_common_sigma = 0.01         # the gain common to every channel (their mean; a shared amplifier or DAQ scale)
    inertia_sigma = 0.02             # the relative error of J (kinetic-energy term of the mean balance)
    load_torque_sigma = 0.005        # the relative error of a shaft-torque reading (torque flange, dyno load cell)
    load_power_sigma = 0.03          # the relative error of the shaft torque read as electrical power / (eff omega)
    generator_efficiency = 1.0       # shaft power = electrical power / this (1.0: not stated, losses not added)
    stiffness_sigma = 0.003          # the relative error of the shaft line's section stiffnesses (drive train)
    damping_sigma = 0.02             # the relative error of its section dampings
    tdc_cylinder_reading_deg = [0.0, -0.26, ...]    # each cylinder's own TDC as commissioning read and left it
    tdc_cylinder_reading_sigma_deg = [0.01, ...]    # and that reading's statistical 1-sigma (both: one per cylinder)
    tdc_cylinder_sigmas_deg = [0.03, ...]  # each cylinder's own TDC sigma, where they differ (else the one above)
    gain_sigmas = [0.004, 0.021, ...]      # each channel's own gain sigma, where they differ (else gain_sigma)
    source = "frictionwatch commission, 3 files, 2026-11-28"
    baseline = "{...}"               # the healthy state per load band the alerts compare with (JSON, see below)
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

STATUSES = ("uncalibrated", "commissioned")

# A typical installation that nobody commissioned (the defaults of Calibration):
# - wheel TDC 0.5 deg: a TDC set statically (timing mark, dial gauge) is good to about half a degree; the real
#   TU/e rig's DAQ was stated 1.5 deg off the data's TDC (244.5 vs 243 deg, issue 25) and the independent logs had
#   whole-wheel offsets of 0.8-1.4 deg: 0.5 is a typical, not a worst, value.
# - a cylinder's own TDC 0.2 deg: the throws' angular tolerance and each channel's sampling phase; smaller than the
#   wheel's because one encoder serves every cylinder.
# - gain 3 % per channel: a piezoelectric sensor's sensitivity as calibrated by its maker drifts by a few % with
#   temperature and age (the independent logs' faulty channels read 0.94-0.96); the issue's "typical installation".
# - gain 1 % common to all channels: a shared charge-amplifier range or DAQ scale (a data-sheet accuracy class).
# - J 5 %: the preset's J against what the TU/e coast-downs say (0.0206 against 0.0215 kg m^2, 4.4 %).
# - shaft line stiffness 20 %, damping 50 %: an engine file's stiffnesses are a maker's or a calculation's, the
#   chain_mismatch effect's stated +-20 %; dampings (a viscous damper's, the shaft's hysteresis) are known worse.
#   Commissioning with a second wheel measures them (core.monitor.calibration.drive_train) and writes the
#   correction as a chain_mismatch effect of the model.
# - load as shaft torque 0.5 %: a torque flange is good to 0.05-0.1 % of its range, a dyno's load cell and lever
#   to ~0.25 % of its range, so ~0.5 % of the reading at part load.
# - load as electrical power 3 %: a genset seldom measures shaft torque; the monitor reads the generator's electrical
#   power / omega. The meter (class 0.2-0.5, with its current and voltage transformers ~0.5 % together) is the
#   small part: the generator's own losses (copper, iron, windage, excitation) are 2-4 % of the power of a MW
#   synchronous machine at 50-100 % load (efficiency 96-98 %), and where the engine file states no efficiency the
#   electrical power undercounts the shaft's by that, which the balance books as friction (+20-35 % of genset-v20's
#   friction). 3 % covers that at about 1 sigma; commissioning cannot measure it (no shaft-torque reference), the
#   installation states it: generator_efficiency from the generator's data sheet at the operating load, and
#   load_power_sigma then the meter's and the data sheet's uncertainty (~0.5-1 %).
# None of the three is measured by `frictionwatch commission`; a commissioned model keeps what its file states.
UNCALIBRATED_SOURCE = ("uncalibrated: a typical installation is assumed (TDC +-0.5 deg wheel and +-0.2 deg per "
                       "cylinder, pressure gain +-3 % per channel and +-1 % common, J +-5 %, load +-0.5 % as "
                       "shaft torque or +-3 % as electrical power); `frictionwatch commission` measures TDC, gain "
                       "and J")


@dataclass(frozen=True)
class Calibration:
    """status: "uncalibrated" (assumed, the defaults) or "commissioned" (measured); the 1-sigma of what is still
    unknown after the corrections in the model's effects are applied: tdc_wheel_sigma_deg (common to all cylinders),
    tdc_cylinder_sigma_deg (each cylinder's own; one per cylinder in tdc_cylinder_sigmas_deg where commissioning
    wrote them), gain_sigma (relative, each channel on its own; one per channel in gain_sigmas likewise), gain_common_sigma
    (relative, common to all channels), inertia_sigma (relative J), stiffness_sigma and damping_sigma (relative, the
    shaft line's sections: what is left after a chain_mismatch correction, or the engine file's own uncertainty);
    load_torque_sigma and load_power_sigma (relative, the load as the monitor reads it: a shaft torque, or an
    electrical power over generator_efficiency times the speed: ``load_variance``);
    source: where the numbers come from, in words; baseline: the commissioning recording's healthy state per load
    band, friction and pressure indicators, as the alert engine learns it (service.alert_baseline.Baseline.to_dict
    as JSON text; empty: none). Core does not read it: it travels with the model so that the alerts compare with
    the commissioned engine from the first cycle of any later session, not with whatever state it starts in."""

    status: str = "uncalibrated"
    tdc_wheel_sigma_deg: float = 0.5
    tdc_cylinder_sigma_deg: float = 0.2
    gain_sigma: float = 0.03
    gain_common_sigma: float = 0.01
    inertia_sigma: float = 0.05
    stiffness_sigma: float = 0.2
    damping_sigma: float = 0.5
    load_torque_sigma: float = 0.005
    load_power_sigma: float = 0.03
    generator_efficiency: float = 1.0
    source: str = UNCALIBRATED_SOURCE
    baseline: str = ""
    # what commissioning read of each cylinder's own TDC (its TDC less the median of all) after its corrections: 0
    # where it applied one, the reading itself where it left it (a reading within twice its sigma: the pressure
    # method's own bias on that cylinder, or a true offset too small to apply); () where none was kept (a model
    # commissioned before these were). The TDC watch compares a commissioned cylinder's own
    # offset with this, not with 0 (core.monitor.calibration.tdc_watch): the method's bias is the same at
    # commissioning and while running (genset-v20 cylinder 8 read -0.26 at commissioning and -0.30 to -0.37 deg
    # while running healthy on every seed looked at: design note 40). A cylinder commissioning could not read is
    # kept as 0 +- 0.5 deg (as its calibration sigma is)
    tdc_cylinder_reading_deg: tuple[float, ...] = ()
    tdc_cylinder_reading_sigma_deg: tuple[float, ...] = ()
    # each cylinder's own TDC sigma and each channel's gain sigma where commissioning measured them one by one, what
    # that cylinder's friction carries (design note 170; the scalars above are a summary: the TDC's their rms, the
    # gain's the rms of the channels' sibling-comparison sigmas, which the gain watch's drift limit reads). One rms
    # for every cylinder hid the cylinder that needed it: k9k-4cyl's hidden own TDC offset was within 2 rms sigma in
    # 8 of 10 held-out logs, within 2 of its own in 10 of 10; a channel's gain correction that a cylinder's own
    # charge could have made (its whole size) is in its own only. () where none was kept (the uncalibrated
    # defaults, a model commissioned before these were): the scalar for every cylinder
    tdc_cylinder_sigmas_deg: tuple[float, ...] = ()
    gain_sigmas: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        if self.status not in STATUSES:
            raise ValueError(f"calibration status {self.status!r} is not one of {', '.join(STATUSES)}")
        for name in ("tdc_wheel_sigma_deg", "tdc_cylinder_sigma_deg", "gain_sigma", "gain_common_sigma",
                     "inertia_sigma", "stiffness_sigma", "damping_sigma", "load_torque_sigma", "load_power_sigma",
                     "generator_efficiency"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) and v >= 0.0):
                raise ValueError(f"calibration {name} = {v!r} must be a number >= 0")
        readings = (self.tdc_cylinder_reading_deg, self.tdc_cylinder_reading_sigma_deg)
        if not all(isinstance(r, tuple) for r in readings) or len(readings[0]) != len(readings[1]):
            raise ValueError("calibration tdc_cylinder_reading_deg and tdc_cylinder_reading_sigma_deg must be two "
                             "lists of one number per cylinder")
        for v, s in zip(*readings, strict=True):
            ok = isinstance(v, float | int) and isinstance(s, float | int) and not isinstance(v, bool)
            if not (ok and math.isfinite(v) and math.isfinite(s) and abs(v) <= 10.0 and s >= 0.0):
                raise ValueError(f"calibration TDC reading {v!r} +- {s!r} deg is not a reading (finite, |deg| <= 10, "
                                 "sigma >= 0)")
        for name in ("tdc_cylinder_sigmas_deg", "gain_sigmas"):
            v = getattr(self, name)
            bound = 10.0 if name.startswith("tdc") else 0.5
            if not (isinstance(v, tuple) and all(isinstance(x, float | int) and not isinstance(x, bool)
                                                 and math.isfinite(x) and 0.0 <= x < bound for x in v)):
                raise ValueError(f"calibration {name} must be a list of one sigma per cylinder (finite, >= 0, "
                                 f"< {bound:g})")
        if self.tdc_cylinder_sigmas_deg and self.gain_sigmas and (len(self.tdc_cylinder_sigmas_deg)
                                                                   != len(self.gain_sigmas)):
            raise ValueError("calibration tdc_cylinder_sigmas_deg and gain_sigmas must have one number per cylinder "
                             "each")
        if not isinstance(self.baseline, str) or not isinstance(self.source, str):
            raise ValueError("calibration source and baseline must be text")
        if (max(self.gain_sigma, self.gain_common_sigma, self.inertia_sigma, self.load_torque_sigma,
                self.load_power_sigma) >= 0.5 or self.tdc_wheel_sigma_deg > 10.0):
            raise ValueError("calibration sigmas beyond 50 % of gain, J or load, or 10 deg of TDC, are not a calibration")
        if not 0.5 <= self.generator_efficiency <= 1.0:
            raise ValueError(f"calibration generator_efficiency = {self.generator_efficiency!r} is not an efficiency "
                             "(0.5 .. 1.0; 1.0: not stated)")
        # tdc_wheel_sigma_rad, tdc_cylinder_sigma_rad: the two TDC sigmas in radians, made once here (plain attributes,
        # not fields: to_dict and KEYS are the record's fields as before); as properties the monitor's estimate
        # called back into this file four times a cycle (design note 82)
        object.__setattr__(self, "tdc_wheel_sigma_rad", math.radians(self.tdc_wheel_sigma_deg))
        object.__setattr__(self, "tdc_cylinder_sigma_rad", math.radians(self.tdc_cylinder_sigma_deg))

    @property
    def commissioned(self) -> bool:
        return self.status == "commissioned"

    def own_variances(self, n_cyl: int) -> np.ndarray:
        """(2, n_cyl): each cylinder's own TDC variance [rad^2] and its channel's gain variance (relative^2), from
        the per-cylinder lists where kept, else the scalar for every cylinder (ValueError: a list of another
        length; engine_model refuses such a model when it loads)."""
        out = np.empty((2, n_cyl))
        for row, (many, one, scale) in enumerate(((self.tdc_cylinder_sigmas_deg, self.tdc_cylinder_sigma_deg,
                                                   math.pi / 180.0), (self.gain_sigmas, self.gain_sigma, 1.0))):
            if many and len(many) != n_cyl:
                raise ValueError(f"the calibration has {len(many)} per-cylinder sigmas for {n_cyl} cylinders")
            out[row] = (np.asarray(many, dtype=np.float64) if many else one) * scale
        return out * out

    def load_variance(self, load_nm: float, from_power: bool) -> float:
        """[N^2 m^2] the variance the load reading's remaining error gives the balance's load ``load_nm`` (a
        relative error: the reading's gain; 0 where the load is not finite). ``from_power``: read as electrical power."""
        rel = self.load_power_sigma if from_power else self.load_torque_sigma
        return (rel * load_nm) ** 2 if math.isfinite(load_nm) else 0.0

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


KEYS = tuple(f.name for f in dataclasses.fields(Calibration))


def calibration_from_dict(table: Mapping) -> Calibration:
    """A ``[model.calibration]`` table; unknown keys refused (ValueError naming them). Missing keys keep the
    uncalibrated defaults, except ``source``, which says "commissioned" where the status is."""
    unknown = sorted(set(table) - set(KEYS))
    if unknown:
        raise ValueError(f"[model.calibration] has unknown key(s) {', '.join(unknown)}; known: {', '.join(KEYS)}")
    values = dict(table)
    for key in ("tdc_cylinder_reading_deg", "tdc_cylinder_reading_sigma_deg", "tdc_cylinder_sigmas_deg",
                "gain_sigmas"):
        if isinstance(values.get(key), list):
            values[key] = tuple(values[key])
    if values.get("status") == "commissioned" and "source" not in values:
        values["source"] = "commissioned (no source given)"
    return Calibration(**values)


def calibration_toml(cal: Calibration) -> str:
    """The ``[model.calibration]`` table as TOML text (empty for the uncalibrated defaults: nothing to say)."""
    if cal == Calibration():
        return ""
    lines = ["[model.calibration]"]
    for key, value in cal.to_dict().items():
        if key == "baseline" and not value:
            continue
        if isinstance(value, str):  # a JSON string (ASCII, escaped) is a TOML basic string
            lines.append(f"{key} = {json.dumps(value)}")
        elif isinstance(value, tuple):  # a TOML array of floats
            if value:
                lines.append(f"{key} = [{', '.join(repr(float(v)) for v in value)}]")
        else:
            lines.append(f"{key} = {float(value)!r}")
    return "\n".join(lines) + "\n"


__all__ = ["KEYS", "STATUSES", "UNCALIBRATED_SOURCE", "Calibration", "calibration_from_dict", "calibration_toml"]
