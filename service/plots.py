"""PNG plots for `frictionwatch analyze --plot DIR`: friction torque vs crank angle per cylinder, measured vs model
flywheel speed, per-cylinder friction with its uncertainty over the run. Matplotlib with the Agg backend (no screen).
Each file is written whole or not at all (service.output_files.atomic_output)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from frictionwatch.core.monitor.figure_status import friction_status  # noqa: E402
from frictionwatch.service.output_files import atomic_output  # noqa: E402
from frictionwatch.service.pipeline import LogAnalysis  # noqa: E402


def write_plots(analysis: LogAnalysis, out_dir: Path) -> list[Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    last = analysis.last
    if last is None:
        return []
    deg = np.degrees(last.grid)
    paths = []

    fig, ax = plt.subplots(figsize=(10, 5))
    for k in range(last.n_cyl):
        ax.plot(deg, last.friction_torque_cyl[k], lw=0.8, label=f"cyl {k + 1}")
    ax.plot(deg, last.friction_torque, "k", lw=1.5, label="total")
    ax.set(xlabel="crank angle [°CA, 0 = cyl 1 firing TDC]", ylabel="friction torque [N·m]",
           title=f"{analysis.spec.name}: friction torque, cycle {last.index} (smoothed coefficients)")
    ax.legend(ncol=4 if last.n_cyl > 4 else 1, fontsize=7)
    paths.append(_save(fig, out_dir / "friction_torque_vs_angle.png"))

    fig, ax = plt.subplots(figsize=(10, 4))
    ax.plot(deg, last.speed_measured * 30 / np.pi, lw=1.0, label="measured")
    ax.plot(deg, last.speed_model * 30 / np.pi, lw=1.0, ls="--", label="model")
    ax.set(xlabel="crank angle [°CA]", ylabel="flywheel speed [rpm]",
           title=f"flywheel speed, cycle {last.index}: residual {last.residual_rms * 30 / np.pi:.3f} rpm rms, "
                 f"R² {last.r_squared:.3f}")
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
