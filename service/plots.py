"""PNG plots for `frictionwatch analyze --plot DIR`: friction torque vs crank angle per cylinder, measured vs model
flywheel speed, per-cylinder friction with its uncertainty over the run. Matplotlib with the Agg backend (no screen).
Each file is written whole or not at all (service.output_files.atomic_output).

A curve is drawn as what its figure's status (core.monitor.report.figure_status, the same as the JSON's) says it is:
a measured figure solid; a share or the prior dashed and labelled as the model's shape, not a measurement; an
unresolved or withheld figure not drawn, named with its status in the plot's note (``angle_curves``)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from frictionwatch.core.monitor.report.figure_status import FigureStatus, FrictionStatus, friction_status  # noqa: E402
from frictionwatch.core.monitor.report.run_summary import end_of_run_status  # noqa: E402
from frictionwatch.service.output_files import atomic_output  # noqa: E402
from frictionwatch.service.pipeline import LogAnalysis  # noqa: E402


@dataclass(frozen=True)
class Curve:
    """One friction-vs-angle curve: ``cylinder`` (1-based; None for the engine total), its legend label, and
    ``measured`` (solid) or the model's shape (dashed)."""

    cylinder: int | None
    label: str
    measured: bool


def angle_curves(status: FrictionStatus) -> tuple[list[Curve], list[str]]:
    """The curves of the friction-vs-angle plot and, for the figures not drawn, one note each, from the run's
    status: measured -> drawn as a measurement; share / prior -> drawn as the model's shape (its coefficients with
    this cycle's pressure and speed), labelled so; unresolved / withheld -> not drawn."""
    curves: list[Curve] = []
    notes: list[str] = []
    for k, st in [(None, status.engine), *enumerate(status.cylinders, start=1)]:
        name = "total" if k is None else f"cyl {k}"
        curve = _curve(k, name, st)
        if curve is None:
            notes.append(f"{name}: {st.status}, not drawn" + (f" ({st.reason})" if st.reason else ""))
        else:
            curves.append(curve)
    return curves, notes


def _curve(k: int | None, name: str, st: FigureStatus) -> Curve | None:
    if st.status == "measured":
        return Curve(k, f"{name} (measured)", True)
    if st.status == "share":
        return Curve(k, f"{name}: model's shape (a share, not measured)", False)
    if st.status == "prior":
        return Curve(k, f"{name}: model's prior shape (not measured)", False)
    return None


def write_plots(analysis: LogAnalysis, out_dir: Path, status: FrictionStatus | None = None) -> list[Path]:
    """The three PNGs in ``out_dir``; ``status``: the run's figure status (default: the one `analyze` reports,
    core.monitor.report.run_summary.end_of_run_status)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    last = analysis.last
    if last is None:
        return []
    if status is None:
        status = end_of_run_status(analysis.results)[2]
    deg = np.degrees(last.grid)
    paths = []

    fig, ax = plt.subplots(figsize=(10, 5))
    curves, notes = angle_curves(status)
    for c in curves:
        trace = last.friction_torque if c.cylinder is None else last.friction_torque_cyl[c.cylinder - 1]
        ax.plot(deg, trace, color="k" if c.cylinder is None else None, lw=1.5 if c.cylinder is None else 0.8,
                ls="-" if c.measured else "--", label=c.label)
    if notes:
        ax.text(0.01, 0.99, "\n".join(notes[:6] + ([f"... and {len(notes) - 6} more"] if len(notes) > 6 else [])),
                transform=ax.transAxes, va="top", fontsize=7, bbox={"facecolor": "white", "alpha": 0.8, "lw": 0})
    ax.set(xlabel="crank angle [°CA, 0 = cyl 1 firing TDC]", ylabel="friction torque [N·m]",
           title=f"{analysis.spec.name}: friction torque, cycle {last.index} (solid: measured; dashed: the model's "
                 "shape, not a measurement)")
    if curves:
        ax.legend(ncol=4 if last.n_cyl > 4 else 1, fontsize=7, loc="lower right")
    paths.append(_save(fig, out_dir / "friction_torque_vs_angle.png"))

    fig, ax = plt.subplots(figsize=(10, 4))
    ax.plot(deg, last.speed_measured * 30 / np.pi, lw=1.0, label="measured")
    ax.plot(deg, last.speed_model * 30 / np.pi, lw=1.0, ls="--", label="model")
    ax.set(xlabel="crank angle [°CA]", ylabel="flywheel speed [rpm]",
           title=f"flywheel speed, cycle {last.index}: residual {last.residual_rms * 30 / np.pi:.3f} rpm rms, "
                 f"R² {last.r_squared:.3f}" + (" (below the floor: the fit is not supported by the data)"
                                                 if "speed_fit_poor" in last.flags else ""))
    ax.legend()
    paths.append(_save(fig, out_dir / "speed_measured_vs_model.png"))

    fig, ax = plt.subplots(figsize=(10, 5))
    cycles = np.array([r.index for r in analysis.results])
    status = [friction_status(r.smoothed, r.flags) for r in analysis.results]  # only measured values are drawn
    for k in range(last.n_cyl):
        mean = np.array([r.smoothed.friction_torque_mean[k] if status[i].cylinders[k].status == "measured"
                         else np.nan for i, r in enumerate(analysis.results)])
        sig = np.array([r.smoothed.friction_torque_mean_sigma[k] for r in analysis.results])
        ax.plot(cycles, mean, lw=1.0, label=f"cyl {k + 1}")
        ax.fill_between(cycles, mean - 2 * sig, mean + 2 * sig, alpha=0.15)
    ax.set(xlabel="cycle", ylabel="mean friction torque [N·m]",
           title="per-cylinder friction resolved from the data (smoothed, ±2σ; gaps: not resolved)")
    ax.legend(ncol=4 if last.n_cyl > 4 else 1, fontsize=7)
    paths.append(_save(fig, out_dir / "friction_per_cylinder_trend.png"))
    return paths


def _save(fig: plt.Figure, path: Path) -> Path:
    try:
        fig.tight_layout()
        with atomic_output(path, "wb") as fh:
            fig.savefig(fh, dpi=110, format="png")
    finally:
        plt.close(fig)
    return path
