"""The commissioning baseline of the alerts (service.alerts): what each healthy cylinder reads against its siblings.

A healthy cylinder is not its siblings' median: fuel spread, heat transfer and its own sensor (a gain or TDC error
the calibration left) give it a persistent offset in every pressure indicator. The baseline learns, per cylinder, the
mean and the per-cycle covariance of the indicators (core.monitor.ring_pressure, sibling-relative) over the first
healthy cycles, so the alerts see a change from the engine's own commissioning state, in units of its own scatter;
and each cylinder's friction excess over its siblings when that friction is first measured. No physics here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# the indicators compared (fields of core.monitor.ring_pressure.RingIndicators), in this order everywhere
INDICATORS = ("compression_ratio", "n_compression_dev", "n_expansion_dev", "expansion_deficit")
VERSION = 1


@dataclass(frozen=True)
class Baseline:
    """mean (4, z), cov (z, 4, 4) of the indicators over ``cycles`` healthy cycles first_cycle..last_cycle;
    friction_excess (z,) each cylinder's friction over its measured siblings' mean minus 1 when first measured
    (NaN: not yet) and its 1-sigma ``friction_excess_sigma`` (z,), ``friction_cycle`` (z,) the cycle it was taken
    (-1: not yet)."""

    mean: np.ndarray
    cov: np.ndarray
    cycles: int
    first_cycle: int
    last_cycle: int
    friction_excess: np.ndarray
    friction_excess_sigma: np.ndarray
    friction_cycle: np.ndarray

    @property
    def sd(self) -> np.ndarray:
        """(4, z) per-cycle standard deviation of each indicator."""
        return np.sqrt(np.maximum(np.diagonal(self.cov, axis1=1, axis2=2).T, 0.0))

    def with_friction(self, k: int, excess: float, sigma: float, cycle: int) -> Baseline:
        fe, fs, fc = self.friction_excess.copy(), self.friction_excess_sigma.copy(), self.friction_cycle.copy()
        fe[k], fs[k], fc[k] = excess, sigma, cycle
        return Baseline(self.mean, self.cov, self.cycles, self.first_cycle, self.last_cycle, fe, fs, fc)

    def to_dict(self) -> dict:
        """JSON-able (None for NaN); ``from_dict`` reads it back exactly."""
        def num(a: np.ndarray) -> list:
            return [None if not np.isfinite(v) else float(v) for v in np.asarray(a, dtype=float).ravel()]
        z = self.mean.shape[1]
        return {"version": VERSION, "n_cylinders": z, "cycles": self.cycles, "first_cycle": self.first_cycle,
                "last_cycle": self.last_cycle, "indicators": list(INDICATORS),
                "mean": [num(row) for row in self.mean], "cov": [num(c) for c in self.cov],
                "friction_excess": num(self.friction_excess),
                "friction_excess_sigma": num(self.friction_excess_sigma),
                "friction_cycle": [int(c) for c in self.friction_cycle]}

    @classmethod
    def from_dict(cls, d: dict) -> Baseline:
        """A baseline from ``to_dict`` output; ValueError (one line) for anything else."""
        try:
            if d.get("version") != VERSION or list(d["indicators"]) != list(INDICATORS):
                raise ValueError(f"baseline version {d.get('version')!r} / indicators not understood")
            z = int(d["n_cylinders"])
            def arr(x, shape):
                a = np.array([np.nan if v is None else float(v) for v in np.ravel(np.array(x, dtype=object))])
                return a.reshape(shape)
            out = cls(arr(d["mean"], (len(INDICATORS), z)), arr(d["cov"], (z, len(INDICATORS), len(INDICATORS))),
                      int(d["cycles"]), int(d["first_cycle"]), int(d["last_cycle"]),
                      arr(d["friction_excess"], (z,)), arr(d["friction_excess_sigma"], (z,)),
                      np.array(d["friction_cycle"], dtype=int).reshape(z))
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"not a baseline: {exc}") from None
        if out.cycles < 2 or not np.all(np.isfinite(out.mean)) or not np.all(np.isfinite(out.cov)):
            raise ValueError("not a baseline: needs >= 2 cycles and finite indicator statistics")
        return out


class BaselineLearner:
    """Running mean and covariance (Welford) of the indicators (4, z) over the cycles it is given."""

    def __init__(self, n_cyl: int):
        self.n = 0
        self.first_cycle = -1
        self.last_cycle = -1
        self.mean = np.zeros((len(INDICATORS), n_cyl))
        self.m2 = np.zeros((n_cyl, len(INDICATORS), len(INDICATORS)))

    def add(self, x: np.ndarray, cycle: int) -> None:
        """Fold one cycle's indicators (4, z) (all finite: the caller checks)."""
        self.n += 1
        self.first_cycle = cycle if self.first_cycle < 0 else self.first_cycle
        self.last_cycle = cycle
        d = x - self.mean
        self.mean = self.mean + d / self.n
        d2 = x - self.mean
        self.m2 += np.einsum("iz,jz->zij", d, d2)

    def baseline(self) -> Baseline:
        z = self.mean.shape[1]
        nan = np.full(z, np.nan)
        return Baseline(self.mean.copy(), self.m2 / max(self.n - 1, 1), self.n, self.first_cycle, self.last_cycle,
                        nan, nan.copy(), np.full(z, -1))
