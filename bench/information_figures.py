"""The information analysis' table and figures (bench/information_v20.py report): cycles each cylinder needs per
configuration, the bound against the number of cycles, and the floors no number of cycles removes."""

from __future__ import annotations

from pathlib import Path

import numpy as np

FIG_DIR = Path(__file__).resolve().parents[1] / "docs" / "information"


def print_table(doc: dict) -> None:
    names = list(doc["configurations"])
    print("cycles for a cylinder's friction sigma <= 2.5 % (data only; with the monitor's sibling prior):")
    print("cyl  " + "  ".join(f"{n:>26s}" for n in names))
    z = len(doc["configurations"][names[0]]["cycles_needed"])
    for k in range(z):
        cells = []
        for n in names:
            c = doc["configurations"][n]
            a, b = c["cycles_needed"][k], c["cycles_needed_with_siblings"][k]
            cells.append(f"{_fmt(a):>12s} ({_fmt(b):>11s})")
        print(f"{k + 1:3d}  " + "  ".join(f"{x:>26s}" for x in cells))
    for n in names:
        print(f"{n}: {doc['configurations'][n]['resolved_at_45000']} of {z} at sigma <= 2.5 % after 45,000 cycles")


def _fmt(v) -> str:
    return ">1e7" if v is None else f"{v:,d}"


def figures(doc: dict, curves: dict, truth: np.ndarray, n_grid: np.ndarray, target: float) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    FIG_DIR.mkdir(parents=True, exist_ok=True)
    z = truth.shape[0]
    fig, ax = plt.subplots(figsize=(8, 5))
    for (name, sig), col in zip(curves.items(), ("C4", "C0", "C1", "C2", "C3")):
        ax.loglog(n_grid, 100 * np.median(sig, axis=1), color=col, label=f"{name}: median cylinder")
        ax.loglog(n_grid, 100 * np.max(sig, axis=1), color=col, ls="--", label=f"{name}: worst cylinder")
    ax.axhline(100 * target, color="k", lw=0.8)
    ax.axvline(45000, color="grey", lw=0.8, ls=":")
    ax.set_xlabel("cycles")
    ax.set_ylabel("Cramér-Rao 1-sigma of a cylinder's friction [%]")
    ax.set_title("genset-v20: friction per cylinder from the tooth times (no floors)")
    ax.legend(fontsize=7)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(FIG_DIR / "crb_vs_cycles.png", dpi=110)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(9, 4.5))
    x = np.arange(1, z + 1)
    for i, (name, c) in enumerate(doc["configurations"].items()):
        need = np.array([1e7 if v is None else v for v in c["cycles_needed"]], dtype=float)
        ax.bar(x + (i - 2) * 0.16, need, width=0.16, label=name)
    ax.set_yscale("log")
    ax.axhline(45000, color="k", lw=0.8, ls=":")
    ax.set_xticks(x)
    ax.set_xlabel("cylinder (A1, B1, A2, ...)")
    ax.set_ylabel("cycles for sigma <= 2.5 %")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(FIG_DIR / "cycles_needed.png", dpi=110)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(9, 4.5))
    fl = doc["floors"]
    base = f"{doc['base_load']:.2f}"
    ax.plot(x, 100 * np.array(fl["tdc_0.1deg"][base]), "o-", label="TDC 0.1 deg")
    ax.plot(x, 100 * np.array(fl["gain_1pct"][base]) * 0.5, "s-", label="pressure gain 0.5 %")
    ax.plot(x, 100 * np.array(fl["model_rel_error"]), "^-", label="model error 0.3 % of each harmonic (monitor)")
    ax.plot(x, 100 * np.array(fl["model_rel_error_two_wheels"]), "^--", label="model error 0.3 %, two wheels")
    ax.axhline(100 * target, color="k", lw=0.8)
    ax.set_yscale("log")
    ax.set_xticks(x)
    ax.set_xlabel("cylinder")
    ax.set_ylabel("1-sigma of the cylinder's friction [%]")
    ax.set_title(f"floors no number of cycles removes (load {base})")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(FIG_DIR / "floors.png", dpi=110)
    plt.close(fig)
