"""The pressure channel of the discrepancy workflow: what each cylinder's pressure says against what a model states.

- Its TDC (the pipeline's TDC watch, read in every monitor run: Residuals.tdc_deg) proposes TDC candidates' starting
  values (``pressure_seeds``) and scores each model beside the speed and balance channels (``tdc_chi2``).
- Its pegging (the same watch's fit), its burns (the monitor's misfire check) and its compression against the
  siblings' (the monitor's blow-by check) name three effects outright (``pressure_findings``): a sensor offset, a
  misfiring cylinder and a leak past the rings. None is a question for the speed: a constant offset does no work
  over a cycle and the monitor reads every misfire and every leak in the pressure it measures, so the speed gap
  hardly moves (genset-v20: pegging 1.5 bar and misfire 30 % both read "nothing" through the speed alone; k9k 1800
  rpm, a 12 % leak: "nothing", design note 97) while the pressure shows them cycle by cycle.
- A leak (effect blow_by) is named where the monitor's condition check called the cylinder's compression a leak
  (blow_by_cyl<k> or ring_wear_cyl<k>: its compression rise, peak and work below the siblings' beyond their healthy
  scatter) in both halves of the log; its size, mass_loss, from the compression pressure's deficit against the
  siblings (``leak_size``: per unit deficit 1 / (gamma x the leak's share gone by the reading, read from the log's
  own pressure: leak_share.py) x a tuned scale, tuned.json BLOW_BY_SHARE_SCALE, design note 149). A single cylinder has no siblings: the
  monitor raises no such flag and nothing is named (words.ONE_CYLINDER_LEAK says why in the verdict).
- A TDC offset far beyond its reading's sigma is named from the pressure too, held at the reading (design note 43):
  the speed's refinement of a TDC offset takes whatever else moves the indicated work along with it (deutz 3000 rpm,
  TDC 1.5 deg and a worn ring: the pressure read 1.444 deg, the speed's fit went to 3.37 deg and the ring's friction
  with it, so the ring was named 3.62 for 2.5 and the TDC never), while the pressure's thermodynamic fit reads the
  phase of the cylinder's own compression and expansion, which no friction moves (healthy, worn-ring, friction-law,
  load-ripple and pegging logs: |TDC| <= 0.12 deg, sigma ~0.2 deg). A smaller reading stays a starting point
  (``pressure_seeds``) for the speed, which weighs it against the pressure (``tdc_chi2``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from frictionwatch.core.discrepancy.leak_share import LEAK_GAMMA
from frictionwatch.core.discrepancy.residuals import Residuals
from frictionwatch.core.discrepancy.tuned import tuned_constants
from frictionwatch.core.model.effects import EFFECTS
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.model.engine_model import EngineModel
from frictionwatch.core.model.kinematics import kinematics
from frictionwatch.core.monitor.checks.ring_pressure import ring_windows
from frictionwatch.core.monitor.checks.sensor_health import SensorHealthConfig

# a TDC reading from the pressure proposes a candidate (it is not a decision: the held-out test decides) when it is
# beyond SEED_SIGMAS of its sigma and SEED_MIN_DEG
SEED_SIGMAS = 2.0
SEED_MIN_DEG = 0.2


def tdc_beyond(res: Residuals, sigmas: float, min_deg: float) -> list[tuple[int, float, float]]:
    """[(cylinder, offset [deg], its sigma [deg])] of the TDC offsets each cylinder's pressure reads in the run
    ``res`` beyond ``sigmas`` x their sigma and ``min_deg``: the whole wheel (cylinder 0) at the median reading (every
    cylinder off alike; its sigma the median sigma), then each cylinder at its own reading less the wheel's where
    the wheel is beyond; on a one-cylinder engine its one offset, as cylinder 1 (the library offers it so)."""
    if res.tdc_deg is None or not np.any(np.isfinite(res.tdc_deg)):
        return []
    ok = np.isfinite(res.tdc_deg)
    wheel, wheel_sigma = float(np.median(res.tdc_deg[ok])), float(np.median(res.tdc_sigma_deg[ok]))
    wheel_beyond = abs(wheel) > max(sigmas * wheel_sigma, min_deg)
    if res.tdc_deg.size == 1:
        return [(1, wheel, wheel_sigma)] if wheel_beyond else []
    out = [(0, wheel, wheel_sigma)] if wheel_beyond else []
    for k in np.flatnonzero(ok):
        own, sigma = float(res.tdc_deg[k]) - (wheel if wheel_beyond else 0.0), float(res.tdc_sigma_deg[k])
        if abs(own) > max(sigmas * sigma, min_deg):
            out.append((int(k) + 1, own, sigma))
    return out


def pressure_seeds(res: Residuals) -> dict[str, float]:
    """{candidate label: start value [deg]} from each cylinder's TDC offset read from its pressure in the run
    ``res`` (``tdc_beyond`` SEED_SIGMAS and SEED_MIN_DEG)."""
    return {f"tdc_offset[cyl {k}]": deg for k, deg, _ in tdc_beyond(res, SEED_SIGMAS, SEED_MIN_DEG)}


def tdc_offsets_deg(model: EngineModel) -> np.ndarray:
    """(z,) each cylinder's TDC offset the model states [deg] (its tdc_offset effects; cylinder 0: every one)."""
    out = np.zeros(model.spec.n_cyl)
    for e in model.effects:
        if e.name == "tdc_offset":
            k = e.values["cylinder"]
            out[slice(None) if k == 0 else k - 1] += e.values["deg"]
    return out


def tdc_chi2(res: Residuals, moved_deg: np.ndarray) -> float:
    """The pressure channel's chi^2: each cylinder's TDC offset read from its pressure in the run ``res``, less what a
    model moves it by against that run's model (``moved_deg`` (z,)), over the reading's sigma; 0 without a reading."""
    if res.tdc_deg is None:
        return 0.0
    ok = np.isfinite(res.tdc_deg) & np.isfinite(res.tdc_sigma_deg) & (res.tdc_sigma_deg > 0)
    return float(np.sum(((res.tdc_deg[ok] - moved_deg[ok]) / res.tdc_sigma_deg[ok]) ** 2))


_HEALTH = SensorHealthConfig()
# a pegging reading names a sensor offset beyond the sensor-health flag's sigmas and threshold (0.2 bar, the same
# commissioning corrects from: core.monitor.calibration.commission.PEGGING_MIN_PA); its sigma adds the floor the
# method cannot resolve (SensorHealthConfig.floor_offset_pa, 0.02 bar) to the reading's own (sampling, and what a
# wall heat off by its sigma or a loss the model lacks moves it by, as the TDC's). Healthy logs read |pegging| <=
# 0.034 bar (k9k 1800/3000 rpm, maruti 1500/4000 rpm, seeds 1-2): no new number is tuned here.
PEG_SIGMAS = _HEALTH.flag_sigmas
PEG_MIN_PA = _HEALTH.offset_pa
PEG_FLOOR_PA = _HEALTH.floor_offset_pa
# a cylinder is named misfiring when the monitor called its burn a misfire in at least MISFIRE_MIN_CYCLES cycles and
# in both halves of the log (a pattern, not one odd cycle), and the rate is beyond MISFIRE_SIGMAS binomial sigmas of
# zero. MISFIRE_MIN_CYCLES = 3 is a pattern, not a tuned threshold: on logs no test uses (bench/pressure_findings.py:
# k9k 2500 rpm 0.8 and 1500 rpm 0.3, maruti 3000 rpm 0.8 and 2000 rpm 0.3, seeds 3-4) no healthy, worn-ring or
# blow-by log had a single misfire flag.
MISFIRE_MIN_CYCLES = 3
MISFIRE_SIGMAS = 3.0
# a TDC offset is named from the pressure (held at its reading, its sigma the reading's: sampling, the method's
# systematic error and what a wall heat or a loss the model lacks moves it by) beyond the sensor-health flag's sigmas
# and its threshold for a cylinder's TDC (SensorHealthConfig.tdc_deg, 0.3 deg). Not tuned here: the largest healthy
# reading on the logs read while building it (deutz 3000 rpm, k9k 3000 rpm, maruti 4000 rpm, seed 2: healthy,
# pegging +-1.5 bar, gain, worn ring, friction laws, load ripples, misfire) was 0.12 deg, sigma 0.15-0.25 deg.
TDC_SIGMAS = _HEALTH.flag_sigmas
TDC_MIN_DEG = _HEALTH.tdc_deg
# a single cylinder has no sibling to burn while it does not: the monitor calls such a cycle motored (one cycle cannot
# tell a misfire from the ignition off). Over a log it can: the ignition off, a coast-down or a motored test is one
# long stretch, a misfire a cycle or a few between burned ones. Runs of motored cycles up to this long, burned cycles
# on both sides, count as misfires (a 30 % misfire makes a run of four 0.8 % of the time).
MISFIRE_MAX_RUN = 3
# a cylinder is named leaking (blow_by) when the monitor's condition check flagged its compression (blow_by_cyl<k> or
# ring_wear_cyl<k>) in at least LEAK_MIN_CYCLES cycles of each half of the log: the flag is a window statistic that
# stays on while the leak lasts, so a pattern in both halves, not a tuned threshold (on the logs of note 97 a healthy,
# gain, pegging, TDC or misfire log had no flag at all; a 12 % leak was flagged in 87-91 of 100 cycles)
LEAK_MIN_CYCLES = 3
# the size: mass_loss = ``leak_per_ln`` x the compression pressure's ln deficit against the siblings' (the ring
# indicators' compression_ratio, read ~30 deg before TDC, before any burn): BLOW_BY_SHARE_SCALE / (LEAK_GAMMA x the
# share of the leak gone by the reading, read from the log's own pressure: leak_share.py), 1 sigma in quadrature:
# the factor's relative spread over the tuning logs (BLOW_BY_REL), a healthy cylinder's own persistent offset from
# its siblings (BLOW_BY_FLOOR_LN: heat transfer, fuel spread), the deficit's standard error over the cycles, and what
# the cylinder's TDC read off by its sigma moves the deficit by (``compression_per_deg``: physics, not tuned)
_TUNED = tuned_constants()
BLOW_BY_SHARE_SCALE = _TUNED["BLOW_BY_SHARE_SCALE"].value
BLOW_BY_REL = _TUNED["BLOW_BY_REL"].value
BLOW_BY_FLOOR_LN = _TUNED["BLOW_BY_FLOOR_LN"].value
# the compression's polytropic exponent in ``compression_per_deg``: k9k and maruti read 1.28-1.33 over the window
COMPRESSION_EXPONENT = 1.3


@dataclass(frozen=True)
class PressureFinding:
    """An effect the pressure names: ``effect`` (pressure_offset, tdc_offset, misfire, blow_by), its cylinder
    (1-based), its parameter and value with 1-sigma, and what the pressure showed, in words."""

    effect: str
    cylinder: int
    parameter: str
    value: float
    sigma: float
    reading: str

    @property
    def label(self) -> str:
        return f"{self.effect}[cyl {self.cylinder}]"


def pressure_findings(res: Residuals, halves: tuple[np.ndarray, np.ndarray] | None = None,
                      spec: EngineSpec | None = None, share: float = math.nan) -> list[PressureFinding]:
    """The effects each cylinder's pressure names in the run ``res`` against that run's model: a pegging beyond
    PEG_SIGMAS of its sigma and PEG_MIN_PA (effect pressure_offset, pa = minus the pegging: the sensor reads p + pa),
    a TDC offset beyond TDC_SIGMAS of its sigma and TDC_MIN_DEG (effect tdc_offset, ``tdc_beyond``: cylinder 0 the
    whole wheel), a misfire rate (effect misfire, probability = the cycles called misfired over those judged) seen
    in both ``halves`` (two boolean masks over the run's cycles; default: its first and second half), a leak (effect
    blow_by, ``leak_findings``: sized by the leak's ``share`` gone by the compression reading (leak_share.leak_share of
    the log's mean pressure; NaN: a leak is not sized, so not named) and ``spec``'s windows (without one its TDC
    term left out))."""
    out: list[PressureFinding] = []
    for k, deg, sigma in tdc_beyond(res, TDC_SIGMAS, TDC_MIN_DEG):
        where = "every cylinder's pressure reads" if k == 0 else "the pressure reads"
        own = " its own" if k and any(c == 0 for c, _, _ in out) else ""
        out.append(PressureFinding("tdc_offset", k, "deg", deg, sigma,
                                   f"{where}{own} TDC {deg:+.2f} +- {sigma:.2f} deg off"))
    if res.pegging_pa is not None:
        own = np.nan_to_num(np.asarray(res.pegging_sigma_pa, dtype=np.float64), nan=0.0)
        sigma = np.sqrt(own**2 + PEG_FLOOR_PA**2)
        for k in np.flatnonzero(np.isfinite(res.pegging_pa)):
            peg = float(res.pegging_pa[k])
            if abs(peg) > max(PEG_SIGMAS * sigma[k], PEG_MIN_PA):
                out.append(PressureFinding("pressure_offset", int(k) + 1, "pa", -peg, float(sigma[k]),
                                           f"the pressure's pegging reads {-peg / 1e5:+.2f} bar"))
    if res.misfired is not None and res.n_cycles:
        n = res.n_cycles
        if halves is None:
            first = np.arange(n) < n // 2
            halves = (first, ~first)
        misfired = res.misfired
        if misfired.shape[1] == 1 and res.motored is not None:
            misfired = misfired | single_cylinder_misfires(res.motored)[:, None]
        for k in range(misfired.shape[1]):
            hits = misfired[:, k]
            count = int(hits.sum())
            rate = count / n
            sigma = math.sqrt(max(rate * (1.0 - rate), 1.0 / n) / n)  # binomial; at 0 or 1 one cycle's worth
            if (count >= MISFIRE_MIN_CYCLES and all(hits[h].any() for h in halves)
                    and rate > MISFIRE_SIGMAS * sigma):
                out.append(PressureFinding("misfire", k + 1, "probability", rate, sigma,
                                           f"the pressure shows no full burn in {count} of {n} cycles"))
    if res.leak_flagged is not None and res.n_cycles:
        out += leak_findings(res, halves, spec, share)
    return out


def leak_findings(res: Residuals, halves: tuple[np.ndarray, np.ndarray] | None = None,
                  spec: EngineSpec | None = None, share: float = math.nan) -> list[PressureFinding]:
    """blow_by findings in the run ``res``: each cylinder the monitor flagged leaking in at least LEAK_MIN_CYCLES
    cycles of each of ``halves`` (default: the run's first and second half), sized by ``leak_size`` with the
    leak's ``share`` gone by the reading (none without a finite share)."""
    if (res.leak_flagged is None or res.compression_ln is None or res.leak_flagged.shape[1] < 2
            or not 0.0 < share < 1.0):
        return []
    n = res.n_cycles
    if halves is None:
        first = np.arange(n) < n // 2
        halves = (first, ~first)
    per_deg = compression_per_deg(spec) if spec is not None else 0.0  # the engine's, once for every cylinder
    out = []
    for k in range(res.leak_flagged.shape[1]):
        hits = res.leak_flagged[:, k]
        if not all(int(hits[h].sum()) >= LEAK_MIN_CYCLES for h in halves):
            continue
        deficit = res.compression_ln[:, k]
        deficit = deficit[np.isfinite(deficit)]
        if deficit.size < 2:
            continue
        value, sigma = leak_size(float(np.mean(deficit)), float(np.std(deficit, ddof=1)) / math.sqrt(deficit.size),
                                 per_deg * sibling_tdc_sigma(res, k), leak_per_ln(share))
        out.append(PressureFinding(
            "blow_by", k + 1, "mass_loss", value, sigma,
            f"the monitor read a leak in {int(hits.sum())} of {n} cycles: the compression pressure "
            f"{100.0 * (math.exp(float(np.mean(deficit))) - 1.0):+.1f} % against the siblings'"))
    return out


def sibling_tdc_sigma(res: Residuals, k: int) -> float:
    """The TDC sigma [deg] a leak's size carries on cylinder ``k`` (0-based): the median of its siblings' TDC
    readings' sigmas. Not its own: the TDC watch puts what a loss the model lacks moves the offset by into the
    leaking cylinder's sigma, and that loss is the leak being sized (k9k 1800 rpm, a 12 % leak on cylinder 2: 0.74
    deg against the siblings' 0.15-0.18; maruti 1500 rpm 0.76 against 0.70). 0 without a reading."""
    if res.tdc_sigma_deg is None:
        return 0.0
    others = np.delete(np.asarray(res.tdc_sigma_deg, dtype=np.float64), k)
    others = others[np.isfinite(others)]
    return float(np.median(others)) if others.size else 0.0


def leak_per_ln(share: float) -> float:
    """The mass_loss a unit ln compression deficit reads when ``share`` of the leak is gone by the reading:
    BLOW_BY_SHARE_SCALE / (LEAK_GAMMA x share) (leak_share.py: the deficit ~ LEAK_GAMMA x share x mass_loss).

    >>> round(leak_per_ln(0.155) * 0.155 * LEAK_GAMMA / BLOW_BY_SHARE_SCALE, 12)
    1.0
    """
    return BLOW_BY_SHARE_SCALE / (LEAK_GAMMA * share)


def leak_size(deficit_ln: float, se_ln: float, tdc_ln: float, per_ln: float) -> tuple[float, float]:
    """(mass_loss, its 1 sigma) from a cylinder's mean ln compression pressure against its siblings' ``deficit_ln``,
    that mean's standard error ``se_ln`` and what its TDC's sigma moves it by ``tdc_ln``, ``per_ln`` the log's
    mass_loss per unit deficit (``leak_per_ln``; module constants' comment). The value is held inside the effect's
    range (blow_by mass_loss: 0-0.4).

    >>> v, s = leak_size(-0.025, 0.0001, 0.0, 5.0)
    >>> round(v, 6)
    0.125
    """
    lo, hi = EFFECTS["blow_by"].parameters["mass_loss"].lo, EFFECTS["blow_by"].parameters["mass_loss"].hi
    value = min(max(-per_ln * deficit_ln, lo), hi)
    sigma = math.sqrt((BLOW_BY_REL * value) ** 2 + (per_ln * math.hypot(BLOW_BY_FLOOR_LN, se_ln, tdc_ln)) ** 2)
    return value, sigma


def compression_per_deg(spec: EngineSpec) -> float:
    """|d ln p / d theta| [1/deg] at the ring indicators' compression reading (ring_pressure.ring_windows'
    comp_end): a TDC off by one degree reads the compression pressure by this much off, COMPRESSION_EXPONENT x
    d(-ln V)/d theta there, over the degree around it (k9k 0.046, maruti 0.034 per deg; a 1.5 deg offset read
    -0.069 and -0.052: design note 97)."""
    at = math.radians(ring_windows(spec).comp_end)
    ends = np.array([at - math.radians(0.5), at + math.radians(0.5)])
    x, _, _ = kinematics(ends, np.asarray(spec.kinematics_params(), dtype=np.float64))
    vol = spec.clearance_volume + spec.piston_area * x
    return COMPRESSION_EXPONENT * abs(math.log(float(vol[0] / vol[1])))


def single_cylinder_misfires(motored: np.ndarray) -> np.ndarray:
    """(N,) the motored cycles of a single-cylinder log that are misfires: those in runs of at most MISFIRE_MAX_RUN
    with a burned cycle on both sides (MISFIRE_MAX_RUN's comment).

    >>> single_cylinder_misfires(np.array([0, 1, 0, 1, 1, 0, 1, 1, 1, 1, 0, 1], bool)).astype(int).tolist()
    [0, 1, 0, 1, 1, 0, 0, 0, 0, 0, 0, 0]
    """
    m = np.asarray(motored, dtype=bool)
    out = np.zeros(m.shape, dtype=bool)
    i, n = 0, m.shape[0]
    while i < n:
        if not m[i]:
            i += 1
            continue
        j = i
        while j < n and m[j]:
            j += 1
        if i > 0 and j < n and j - i <= MISFIRE_MAX_RUN:
            out[i:j] = True
        i = j
    return out


__all__ = ["BLOW_BY_FLOOR_LN", "BLOW_BY_REL", "BLOW_BY_SHARE_SCALE", "LEAK_MIN_CYCLES", "MISFIRE_MIN_CYCLES",
           "PEG_MIN_PA", "PEG_SIGMAS", "PressureFinding", "SEED_MIN_DEG", "SEED_SIGMAS", "TDC_MIN_DEG", "TDC_SIGMAS",
           "compression_per_deg", "leak_findings", "leak_per_ln", "leak_size", "pressure_findings", "pressure_seeds",
           "sibling_tdc_sigma", "single_cylinder_misfires", "tdc_beyond", "tdc_chi2", "tdc_offsets_deg"]
