"""The pressure channel of the discrepancy workflow: what each cylinder's pressure says of its TDC (the pipeline's TDC
watch, read in every monitor run: Residuals.tdc_deg) against what a model states. It proposes TDC candidates'
starting values (``pressure_seeds``) and scores each model beside the speed and balance channels (``tdc_chi2``)."""

from __future__ import annotations

import numpy as np
from frictionwatch.core.discrepancy.residuals import Residuals
from frictionwatch.core.model.engine_model import EngineModel

# a TDC reading from the pressure proposes a candidate (it is not a decision: the held-out test decides) when it is
# beyond SEED_SIGMAS of its sigma and SEED_MIN_DEG
SEED_SIGMAS = 2.0
SEED_MIN_DEG = 0.2


def pressure_seeds(res: Residuals) -> dict[str, float]:
    """{candidate label: start value [deg]} from each cylinder's TDC offset read from its pressure in the run
    ``res``: the whole wheel at the median reading (every cylinder's off alike), each cylinder at its own reading
    less the wheel's, where beyond SEED_SIGMAS x its sigma and SEED_MIN_DEG."""
    if res.tdc_deg is None or not np.any(np.isfinite(res.tdc_deg)):
        return {}
    ok = np.isfinite(res.tdc_deg)
    wheel, wheel_sigma = float(np.median(res.tdc_deg[ok])), float(np.median(res.tdc_sigma_deg[ok]))
    if res.tdc_deg.size == 1:  # one cylinder: its offset is the wheel's (the library offers it once, as cylinder 1)
        return {"tdc_offset[cyl 1]": wheel} if abs(wheel) > max(SEED_SIGMAS * wheel_sigma, SEED_MIN_DEG) else {}
    out = {}
    if abs(wheel) > max(SEED_SIGMAS * wheel_sigma, SEED_MIN_DEG):
        out["tdc_offset[cyl 0]"] = wheel
    for k in np.flatnonzero(ok):
        own = float(res.tdc_deg[k]) - (wheel if "tdc_offset[cyl 0]" in out else 0.0)
        if abs(own) > max(SEED_SIGMAS * float(res.tdc_sigma_deg[k]), SEED_MIN_DEG):
            out[f"tdc_offset[cyl {k + 1}]"] = own
    return out


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


__all__ = ["SEED_MIN_DEG", "SEED_SIGMAS", "pressure_seeds", "tdc_chi2", "tdc_offsets_deg"]
