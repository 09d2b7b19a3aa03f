"""From a commissioning recording's estimates to the engine model the monitor then runs with (issue 25 item 1).

What was measured becomes the model's sensor effects (core.model.effects: ``tdc_offset`` for the wheel and for a
cylinder whose own TDC stands out, ``pressure_gain`` / ``pressure_offset`` for a channel that stands out of its
siblings; core.model.view applies them) and what stays unknown becomes its calibration section
(core.model.calibration, status "commissioned"): the sigmas every friction figure then carries.

Rules, each for a reason:
- The wheel's TDC is the median of the cylinders' thermodynamic TDCs (one faulty channel does not move it) and its
  sigma the median of theirs: the method's systematic part (the wall heat, the losses the model lacks) is the same
  in every cylinder and does not average down.
- A cylinder's own offset (its TDC less the wheel's) is applied where it exceeds twice its whole TDC sigma (and
  twice its own sigma, where that is larger). Its own sigma is its statistical sigma, the method's systematic
  (tdc.SYSTEMATIC_SIGMA_DEG, an rms over cylinder estimates) and the cylinders' robust spread of own offsets (what the method reads differently cylinder by cylinder: on a fired
  genset-v20 +-0.2 deg, the throws' twist at firing beyond the static twist the model takes out), as a channel's
  gain keeps its siblings' spread (pressure_gain). The wheel's heat-loss and constant-loss parts are not in it: the
  same in every cylinder, they leave the difference. Applied, that sigma is what is left; not applied, the reading
  joins it. (Before, a cylinder applied kept its statistical sigma alone, 0.001-0.01 deg, and was 0.05-0.19 deg
  off: design note 163.)
- Fired and motored cycles give two TDCs; where both exist the motored one is used and their difference is reported
  beside it, never averaged away: without a flame the fit has no combustion edges and no constant loss to doubt,
  the wall heat is smaller and a coasting throw hardly twists (the wheel +-0.06-0.08 deg against the fired
  +-0.18-0.21, each cylinder 0.01-0.02 deg off against 0.05-0.19: design note 163).
- J: the coast-downs' pooled J where there is one. The monitor's J is the engine file's (node inertias), so a
  measured J is reported and its disagreement with the file carried in ``inertia_sigma``, not written silently.
- The drive train (a second wheel, core.monitor.calibration.drive_train): a fit that explains both wheels becomes a
  ``chain_mismatch`` effect (the monitor's view scales its chain by it) with the scales' sigmas in the calibration
  section; a poor fit changes nothing, its words say why, and the sigmas stay the engine file's.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from frictionwatch.core.model.calibration import Calibration
from frictionwatch.core.model.effects import make_effect
from frictionwatch.core.model.engine_model import EngineModel
from frictionwatch.core.monitor.calibration.drive_train import DriveTrainFit
from frictionwatch.core.monitor.calibration.pressure_gain import SiblingGains
from frictionwatch.core.monitor.calibration.tdc import TdcEstimate

SENSOR_EFFECTS = ("tdc_offset", "pressure_gain", "pressure_offset")
OWN_TDC_SIGMAS = 2.0  # a cylinder's own TDC offset is applied beyond this many of its sigmas
PEGGING_MIN_PA = 0.2e5  # a pegging correction below this is left (SensorHealthConfig.offset_pa: its flag threshold)


@dataclass(frozen=True)
class InertiaFinding:
    """J measured on coast-downs [kg m^2] and its 1-sigma, the engine file's J, and how many records it pools."""

    inertia: float
    sigma: float
    spec_inertia: float
    records: int


@dataclass(frozen=True)
class Commissioning:
    """The commissioned model and what it rests on (``report``: a JSON-able dict, engineering units)."""

    model: EngineModel
    report: dict = field(default_factory=dict)


def without_sensor_effects(model: EngineModel) -> EngineModel:
    """``model`` with its TDC, gain and pegging corrections removed: commissioning measures them anew against the
    raw readings (a model commissioned before would otherwise be corrected twice). A drive train correction
    (chain_mismatch) is not a sensor's: it stays, and so do its sigmas."""
    kept = tuple(e for e in model.effects if e.name not in SENSOR_EFFECTS)
    cal = Calibration()
    if any(e.name == "chain_mismatch" for e in kept):  # a drive train commissioned before stays, with its sigmas
        cal = Calibration(stiffness_sigma=model.calibration.stiffness_sigma,
                          damping_sigma=model.calibration.damping_sigma)
    return dataclasses.replace(model, effects=kept, calibration=cal)


def tdc_used(fired: Sequence[TdcEstimate | None] | None, motored: Sequence[TdcEstimate | None] | None
             ) -> Sequence[TdcEstimate | None] | None:
    """The TDCs commissioning writes (module doc): the motored cycles' where they gave any, else the fired ones'."""
    if motored is not None and any(t is not None for t in motored):
        return motored
    return fired if fired is not None and any(t is not None for t in fired) else None


def _tdc_part(tdc: Sequence[TdcEstimate | None]) -> tuple[float, float, np.ndarray, np.ndarray,
                                                           tuple[np.ndarray, np.ndarray]]:
    """(wheel rad, wheel sigma rad, own (z,) rad applied, own sigma (z,) rad, each cylinder's reading kept and its
    sigma (z,) rad: ``own_readings``)."""
    found = [t for t in tdc if t is not None]
    if not found:
        raise ValueError("no cylinder's TDC could be found from its pressure (no fired or motored cycle pairs)")
    offsets = np.array([t.offset_rad if t is not None else np.nan for t in tdc])
    sigmas = np.array([t.sigma_rad if t is not None else np.nan for t in tdc])
    stat = np.array([math.radians(t.evidence.get("statistical_deg", math.degrees(t.sigma_rad))) if t is not None
                     else np.nan for t in tdc])
    systematic = np.array([math.radians(t.evidence.get("systematic_deg", 0.0)) if t is not None else np.nan
                           for t in tdc])
    wheel = float(np.nanmedian(offsets))
    wheel_sigma = float(np.nanmedian(sigmas))
    own = offsets - wheel
    spread = 1.4826 * float(np.nanmedian(np.abs(own - np.nanmedian(own))))  # the cylinders' robust spread
    own_read = np.sqrt(stat**2 + systematic**2 + spread**2)  # a cylinder's own offset as read: its 1-sigma
    # applied beyond twice the larger of that and the cylinder's whole TDC sigma: on fired genset-v20 (seeds
    # 201-212, design note 163) twice the own sigma alone applied 11 of 228 healthy cylinders' fired bias (0.25-0.35
    # deg, beyond the robust spread's Gaussian tail); the whole sigma (0.2 deg fired, 0.065 motored) applies none
    apply = np.isfinite(own) & (np.abs(own) > OWN_TDC_SIGMAS * np.maximum(own_read, sigmas))
    own_applied = np.where(apply, own, 0.0)
    # what is left per cylinder: its own sigma where applied, and with the reading where not
    own_sigma = np.where(np.isfinite(own), np.where(apply, own_read, np.hypot(own_read, own)), math.radians(0.5))
    return wheel, wheel_sigma, own_applied, own_sigma, own_readings(own, apply, stat)


def own_readings(own: np.ndarray, applied: np.ndarray, stat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each cylinder's own TDC offset as the pressure will read it once the corrections are in, and that reading's
    statistical sigma [rad] (z,), from its own offset read (NaN: none), whether that was applied and its statistical
    sigma: 0 where a correction was applied (it is the reading), the reading where it was left (the method's own bias
    on that cylinder, which the TDC watch meets again: core.model.calibration), 0 +- 0.5 deg where nothing was read."""
    read = np.isfinite(own) & np.isfinite(stat)
    return np.where(read & ~applied, own, 0.0), np.where(read, stat, math.radians(0.5))


def fired_readings(fired: Sequence[TdcEstimate | None], own_applied: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each cylinder's own TDC offset as the fired cycles' fit will read it once the corrections ``own_applied``
    (z,) [rad] taken from another fit (the motored one) are in, and that reading's statistical sigma [rad] (z,):
    ``own_readings`` where the corrections came from the fired fit itself."""
    offsets = np.array([t.offset_rad if t is not None else np.nan for t in fired]) - own_applied
    stat = np.array([math.radians(t.evidence.get("statistical_deg", math.degrees(t.sigma_rad))) if t is not None
                     else np.nan for t in fired])
    return own_readings(offsets - np.nanmedian(offsets), np.zeros(offsets.shape, dtype=bool), stat)


def commissioned_model(model: EngineModel, tdc_fired: Sequence[TdcEstimate | None] | None,
                       tdc_motored: Sequence[TdcEstimate | None] | None, gains: SiblingGains | None,
                       gain_common_sigma: float, inertia: InertiaFinding | None, source: str) -> Commissioning:
    """The model with the measured corrections as effects and the calibration section (module doc); ``model``
    without sensor effects (``without_sensor_effects``), its drive train's sigmas (``commissioned_drive_train``,
    before) carried into the new calibration section; gain_common_sigma: the relative 1-sigma of the gain common
    to every channel, which the data cannot give (a stated reference)."""
    z = model.spec.n_cyl
    tdc = tdc_used(tdc_fired, tdc_motored)
    if tdc is None:
        raise ValueError("commissioning needs fired or motored cycles to find TDC from")
    wheel, wheel_sigma, own, own_sigma, (reading, reading_sigma) = _tdc_part(tdc)
    if tdc is not tdc_fired and tdc_fired is not None and any(t is not None for t in tdc_fired):
        # the TDC watch runs on fired cycles: what it will read of each cylinder is the fired fit's own offset less
        # the correction written (the fired method's bias on that cylinder, +-0.2 deg on genset-v20, stays in it)
        reading, reading_sigma = fired_readings(tdc_fired, own)
    effects = [make_effect("tdc_offset", {"deg": round(math.degrees(wheel), 4), "cylinder": 0},
                           {"deg": round(math.degrees(wheel_sigma), 4)})]
    for k in np.flatnonzero(own):
        effects.append(make_effect("tdc_offset", {"deg": round(math.degrees(own[k]), 4), "cylinder": int(k) + 1},
                                   {"deg": round(math.degrees(own_sigma[k]), 4)}))
    pegging = np.array([t.pegging_pa if t is not None else 0.0 for t in tdc])
    for k in np.flatnonzero(np.abs(pegging) > PEGGING_MIN_PA):  # the channel reads p - pegging
        effects.append(make_effect("pressure_offset", {"cylinder": int(k) + 1, "pa": round(-float(pegging[k]), 1)}))
    if gains is not None:
        for k in np.flatnonzero(gains.corrected):
            effects.append(make_effect("pressure_gain", {"cylinder": int(k) + 1, "gain": round(float(gains.gain[k]), 5)},
                                       {"gain": round(float(gains.gain_sigma[k]), 5)}))
        gain_sigma = float(np.sqrt(np.mean(gains.gain_sigma ** 2)))  # their rms (the gain watch's drift limit)
        # what each channel's friction carries: a corrected channel's whole correction too. The sibling comparison
        # reads a channel 2-3 % off its siblings as its gain, but a cylinder that traps more charge reads the same
        # over the compression (genset-v20's cylinder 5, design note 19: corrected by 2.3-2.8 % in 6 of 10 held-out
        # logs, each time wrongly, at z 3.7-5.9 in its own stated sigma; design note 170). Nothing in one
        # recording tells the two apart, so the correction stays (the likelier reading beyond 3 spreads) and its
        # sigma holds the other
        gain_sigmas = tuple(round(float(g), 5) for g in np.where(gains.corrected, np.hypot(gains.gain_sigma,
                                                                                          gains.gain - 1.0),
                                                                  gains.gain_sigma))
    else:  # one or two cylinders: no sibling to compare with; each channel as the uncalibrated default
        gain_sigma, gain_sigmas = Calibration().gain_sigma, ()
    inertia_sigma = Calibration().inertia_sigma
    if inertia is not None and inertia.inertia > 0:
        # the monitor runs with the file's J: what it may be off by is the measured difference and its sigma
        inertia_sigma = math.hypot(inertia.inertia / inertia.spec_inertia - 1.0, inertia.sigma / inertia.inertia)
    cal = Calibration(status="commissioned", tdc_wheel_sigma_deg=round(math.degrees(wheel_sigma), 4),
                      tdc_cylinder_sigma_deg=round(math.degrees(float(np.sqrt(np.mean(own_sigma ** 2)))), 4),
                      gain_sigma=round(gain_sigma, 5), gain_common_sigma=round(gain_common_sigma, 5),
                      inertia_sigma=round(min(inertia_sigma, 0.49), 5), stiffness_sigma=model.calibration.stiffness_sigma,
                      damping_sigma=model.calibration.damping_sigma, source=source,
                      # the load reading: not measured here (no shaft-torque reference), kept as the file states it
                      load_torque_sigma=model.calibration.load_torque_sigma,
                      load_power_sigma=model.calibration.load_power_sigma,
                      generator_efficiency=model.calibration.generator_efficiency,
                      tdc_cylinder_reading_deg=tuple(round(math.degrees(float(v)), 4) for v in reading),
                      tdc_cylinder_reading_sigma_deg=tuple(round(math.degrees(float(v)), 4) for v in reading_sigma),
                      # each cylinder's and channel's own (design note 170); the two scalars above their rms
                      tdc_cylinder_sigmas_deg=tuple(round(math.degrees(float(v)), 4) for v in own_sigma),
                      gain_sigmas=gain_sigmas)
    out = dataclasses.replace(model, effects=model.effects + tuple(effects), calibration=cal)
    return Commissioning(out, _report(z, tdc_fired, tdc_motored, wheel, wheel_sigma, own, gains, pegging, inertia,
                                      cal))


def commissioned_drive_train(model: EngineModel, fit: DriveTrainFit) -> Commissioning:
    """``model`` with the drive train a good ``fit`` identified (module doc): its chain_mismatch effect replaced by
    one of the identified scales (relative to the engine file's chain) and the scales' relative sigmas in the
    calibration section. A poor fit returns ``model`` as it is, with the fit's words in the report."""
    report = {"drive_train": fit.to_dict()}
    if fit.poor:
        report["drive_train"]["applied"] = False
        return Commissioning(model, report)
    prior = [e for e in model.effects if e.name == "chain_mismatch"]  # the fit is relative to the chain it ran with
    k0 = prior[0].values["stiffness_scale"] if prior else 1.0
    d0 = prior[0].values["damping_scale"] if prior else 1.0
    effect = make_effect("chain_mismatch", {"stiffness_scale": round(k0 * fit.stiffness_scale, 5),
                                            "damping_scale": round(d0 * fit.damping_scale, 4)},
                         {"stiffness_scale": round(k0 * fit.stiffness_sigma, 5),
                          "damping_scale": round(d0 * fit.damping_sigma, 4)})
    kept = tuple(e for e in model.effects if e.name != "chain_mismatch")
    said = f"drive train from both wheels ({fit.cycles} cycles, chi2 {fit.chi2:.1f} on {fit.dof} dof)"
    cal = dataclasses.replace(model.calibration, status="commissioned",
                              stiffness_sigma=round(fit.stiffness_sigma / fit.stiffness_scale, 5),
                              damping_sigma=round(fit.damping_sigma / fit.damping_scale, 4),
                              source=f"{model.calibration.source}; {said}" if model.calibration.commissioned
                              else f"frictionwatch commission: {said}")
    report["drive_train"]["applied"] = True
    return Commissioning(dataclasses.replace(model, effects=kept + (effect,), calibration=cal), report)


def _tdc_json(t: TdcEstimate | None) -> dict | None:
    if t is None:
        return None
    return {"offset_deg": t.offset_deg, "sigma_deg": t.sigma_deg, "pegging_bar": t.pegging_pa / 1e5,
            "cycles": t.n_cycles, "method": t.method,
            "sigma_parts_deg": {k: t.evidence[k] for k in ("statistical_deg", "systematic_deg", "heat_loss_deg",
                                                           "constant_loss_deg") if k in t.evidence}}


def _report(z: int, fired, motored, wheel: float, wheel_sigma: float, own: np.ndarray, gains: SiblingGains | None,
            pegging: np.ndarray, inertia: InertiaFinding | None, cal: Calibration) -> dict:
    cylinders = []
    for k in range(z):
        f = _tdc_json(fired[k]) if fired is not None else None
        m = _tdc_json(motored[k]) if motored is not None else None
        row = {"cylinder": k + 1, "tdc_fired": f, "tdc_motored": m,
               "own_tdc_offset_deg": math.degrees(float(own[k])), "pegging_bar": float(pegging[k]) / 1e5}
        if cal.tdc_cylinder_reading_deg:  # what the TDC watch will compare this cylinder with (0 where applied)
            row["own_tdc_reading_deg"] = cal.tdc_cylinder_reading_deg[k]
        if f is not None and m is not None:  # two methods: their difference said, not averaged away
            diff = f["offset_deg"] - m["offset_deg"]
            row["fired_minus_motored_deg"] = diff
            row["methods_agree"] = bool(abs(diff) <= 2.0 * math.hypot(f["sigma_deg"], m["sigma_deg"]))
        if gains is not None:
            row.update({"gain_vs_siblings": float(gains.gain[k]), "gain_sigma": float(gains.gain_sigma[k]),
                        "gain_corrected": bool(gains.corrected[k])})
        cylinders.append(row)
    return {
        "wheel_tdc_offset_deg": math.degrees(wheel), "wheel_tdc_sigma_deg": math.degrees(wheel_sigma),
        "gain_reference": "none: a gain common to every channel is not seen by comparing the channels; its sigma is "
                          f"the stated {cal.gain_common_sigma:.3f}",
        "sibling_gain_spread": None if gains is None else gains.spread,
        "inertia": None if inertia is None else {"measured_kgm2": inertia.inertia, "sigma_kgm2": inertia.sigma,
                                                 "engine_file_kgm2": inertia.spec_inertia,
                                                 "records": inertia.records},
        "calibration": cal.to_dict(),
        "cylinders": cylinders,
    }


__all__ = ["Commissioning", "InertiaFinding", "SENSOR_EFFECTS", "commissioned_drive_train", "commissioned_model",
           "fired_readings", "own_readings", "tdc_used", "without_sensor_effects"]
