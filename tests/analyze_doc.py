"""Checks every `analyze --json` document of the test suite passes through (issue 25, "one definition of each
figure"): each FMEP is its friction torque times 4 pi / V_d, V_d one cylinder's swept volume for a cylinder's figure
and the engine's for the engine's."""

from __future__ import annotations

import math

from frictionwatch.core.model.engine import EngineSpec, load_engine

FIGURE_PAIRS = (("friction_torque_mean_nm", "fmep_bar"), ("friction_torque_sigma_nm", "fmep_sigma_bar"))


def _check_figure(fig: dict, bar_per_nm: float, rtol: float, where: str) -> int:
    checked = 0
    for torque_key, mep_key in FIGURE_PAIRS:
        t, m = fig[torque_key], fig[mep_key]
        assert (t is None) == (m is None), f"{where}: {torque_key} {t} but {mep_key} {m}"
        if t is None:
            continue
        assert math.isclose(m, t * bar_per_nm, rel_tol=rtol, abs_tol=0.0), (
            f"{where}: {mep_key} / {torque_key} = {m / t if t else math.nan!r} bar per N m, 4 pi / V_d = "
            f"{bar_per_nm!r}")
        checked += 1
    return checked


def assert_fmep_is_torque_over_displacement(doc: dict, spec: EngineSpec | None = None, rtol: float = 1e-9) -> int:
    """Every friction figure of an analyze document (the flat keys, ``friction``, ``friction_run_mean_balance``,
    each regime's, each cylinder's) has fmep_bar = friction_torque_mean_nm * 4 pi / V_d and the same for its 1-sigma, to ``rtol``;
    V_d computed here from the engine's bore and stroke (``spec``; default the preset the document names). Returns
    how many values were compared (a figure without a value has neither)."""
    spec = load_engine(doc["engine"]) if spec is None else spec
    v_cyl = math.pi / 4.0 * spec.bore ** 2 * spec.stroke  # m^3, from the geometry, not from the package's function
    per_cyl = 4.0 * math.pi / v_cyl / 1e5
    per_engine = per_cyl / spec.n_cyl
    checked = 0
    if "friction" not in doc:  # no analysed cycle
        return 0
    checked += _check_figure(doc, per_engine, rtol, "engine (flat keys)")
    checked += _check_figure(doc["friction"], per_engine, rtol, "engine friction")
    checked += _check_figure(doc["friction_run_mean_balance"], per_engine, rtol, "run mean balance")
    for g in doc.get("regimes", []):
        checked += _check_figure(g["friction"], per_engine, rtol, f"{g['regime']} regime")
    assert len(doc["cylinders"]) == spec.n_cyl
    for c in doc["cylinders"]:
        checked += _check_figure(c, per_cyl, rtol, f"cylinder {c['cylinder']} (flat keys)")
        checked += _check_figure(c["friction"], per_cyl, rtol, f"cylinder {c['cylinder']} friction")
    return checked
