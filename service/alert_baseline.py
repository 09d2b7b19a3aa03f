"""The commissioning baseline of the alerts (service.alerts): what each healthy cylinder reads against its siblings,
per load band.

A healthy cylinder is not its siblings' median: fuel spread, heat transfer and its own sensor (a gain or TDC error
the calibration left) give it a persistent offset in every pressure indicator. The baseline learns, per cylinder, the
mean and the per-cycle covariance of the indicators (core.monitor.checks.ring_pressure, sibling-relative) over the first
healthy cycles, so the alerts see a change from the engine's own commissioning state, in units of its own scatter;
and each cylinder's friction excess over its siblings when that friction is first measured. No physics here.

That offset depends on the load: on genset-v20 a step 0.75 -> 0.45 moves several cylinders' sibling-relative
exponents by ~0.002 in the leak direction (as much as a 3 % leak; on K9K a step 0.69 -> 0.40 moves them by at most
0.0003). So the statistics are kept per load band, a band being a range of the engine's mean IMEP (``Band``): a
cycle is compared with the band that holds its IMEP; at an IMEP no band holds yet the engine is "not commissioned at
this load" and the caller (service.alerts) suspends the pressure alerts while a new band learns over the next
healthy cycles at that IMEP.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

# the indicators compared (fields of core.monitor.checks.ring_pressure.RingIndicators), in this order everywhere
INDICATORS = ("compression_ratio", "n_compression_dev", "n_expansion_dev", "expansion_deficit")
VERSION = 2  # 1: one band, learnt without its IMEP (read back as valid at every load, as it was used)


@dataclass(frozen=True)
class Band:
    """One load band's statistics: mean (4, z), cov (z, 4, 4) of the indicators over ``cycles`` healthy cycles
    first_cycle..last_cycle whose mean IMEP lay in [imep_lo_pa, imep_hi_pa] (the band; -inf..inf for a version-1
    baseline); imep_pa their mean IMEP [Pa]."""

    mean: np.ndarray
    cov: np.ndarray
    cycles: int
    first_cycle: int
    last_cycle: int
    imep_pa: float
    imep_lo_pa: float
    imep_hi_pa: float

    @property
    def sd(self) -> np.ndarray:
        """(4, z) per-cycle standard deviation of each indicator."""
        return np.sqrt(np.maximum(np.diagonal(self.cov, axis1=1, axis2=2).T, 0.0))

    def holds(self, imep_pa: float) -> bool:
        return self.imep_lo_pa <= imep_pa <= self.imep_hi_pa


@dataclass(frozen=True)
class Baseline:
    """bands: the load bands learnt so far, the commissioning band first (``mean``, ``cov``, ``cycles``, ...,
    ``sd`` are its); friction_excess (z,) each cylinder's friction over its measured siblings' mean minus 1 when
    first measured (NaN: not yet) and its 1-sigma ``friction_excess_sigma`` (z,), ``friction_cycle`` (z,) the cycle it
    was taken (-1: not yet)."""

    bands: tuple[Band, ...]
    friction_excess: np.ndarray
    friction_excess_sigma: np.ndarray
    friction_cycle: np.ndarray

    mean = property(lambda self: self.bands[0].mean)
    cov = property(lambda self: self.bands[0].cov)
    sd = property(lambda self: self.bands[0].sd)
    cycles = property(lambda self: self.bands[0].cycles)
    first_cycle = property(lambda self: self.bands[0].first_cycle)
    last_cycle = property(lambda self: self.bands[0].last_cycle)

    def band_for(self, imep_pa: float) -> Band | None:
        """The band holding this mean IMEP (the one whose own IMEP is nearest where bands overlap), or None."""
        held = [b for b in self.bands if b.holds(imep_pa)]
        return min(held, key=lambda b: abs(b.imep_pa - imep_pa)) if held else None

    def with_band(self, band: Band) -> Baseline:
        return replace(self, bands=(*self.bands, band))

    def with_friction(self, k: int, excess: float, sigma: float, cycle: int) -> Baseline:
        fe, fs, fc = self.friction_excess.copy(), self.friction_excess_sigma.copy(), self.friction_cycle.copy()
        fe[k], fs[k], fc[k] = excess, sigma, cycle
        return replace(self, friction_excess=fe, friction_excess_sigma=fs, friction_cycle=fc)

    def to_dict(self) -> dict:
        """JSON-able (None for NaN and for an unbounded band edge); ``from_dict`` reads it back exactly."""
        z = self.mean.shape[1]
        return {"version": VERSION, "n_cylinders": z, "indicators": list(INDICATORS),
                "bands": [{"cycles": b.cycles, "first_cycle": b.first_cycle, "last_cycle": b.last_cycle,
                           "imep_pa": _num(b.imep_pa), "imep_lo_pa": _num(b.imep_lo_pa),
                           "imep_hi_pa": _num(b.imep_hi_pa), "mean": [_nums(row) for row in b.mean],
                           "cov": [_nums(c) for c in b.cov]} for b in self.bands],
                "friction_excess": _nums(self.friction_excess),
                "friction_excess_sigma": _nums(self.friction_excess_sigma),
                "friction_cycle": [int(c) for c in self.friction_cycle]}

    @classmethod
    def from_dict(cls, d: dict) -> Baseline:
        """A baseline from ``to_dict`` output (this version or version 1); ValueError (one line) for anything else."""
        try:
            version = d.get("version")
            if version not in (1, VERSION) or list(d["indicators"]) != list(INDICATORS):
                raise ValueError(f"baseline version {version!r} / indicators not understood")
            z, m = int(d["n_cylinders"]), len(INDICATORS)
            docs = d["bands"] if version == VERSION else [{**d, "imep_pa": None, "imep_lo_pa": None,
                                                           "imep_hi_pa": None}]
            bands = tuple(Band(_arr(b["mean"], (m, z)), _arr(b["cov"], (z, m, m)), int(b["cycles"]),
                               int(b["first_cycle"]), int(b["last_cycle"]), _edge(b["imep_pa"], np.nan),
                               _edge(b["imep_lo_pa"], -np.inf), _edge(b["imep_hi_pa"], np.inf)) for b in docs)
            out = cls(bands, _arr(d["friction_excess"], (z,)), _arr(d["friction_excess_sigma"], (z,)),
                      np.array(d["friction_cycle"], dtype=int).reshape(z))
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise ValueError(f"not a baseline: {exc}") from None
        if not bands or any(b.cycles < 2 or not np.all(np.isfinite(b.mean)) or not np.all(np.isfinite(b.cov))
                            or not b.imep_lo_pa <= b.imep_hi_pa for b in bands):
            raise ValueError("not a baseline: needs bands of >= 2 cycles with finite indicator statistics")
        return out


def _num(v: float) -> float | None:
    return float(v) if np.isfinite(v) else None


def _nums(a: np.ndarray) -> list:
    return [_num(v) for v in np.asarray(a, dtype=float).ravel()]


def _arr(x, shape: tuple) -> np.ndarray:
    return np.array([np.nan if v is None else float(v) for v in np.ravel(np.array(x, dtype=object))]).reshape(shape)


def _edge(v, missing: float) -> float:
    return missing if v is None else float(v)


class BaselineLearner:
    """Running mean and covariance (Welford) of the indicators (4, z) and the mean IMEP over the cycles it is
    given; ``band`` makes them a Band of relative half-width ``width`` around their mean IMEP."""

    def __init__(self, n_cyl: int):
        self.n = 0
        self.first_cycle = -1
        self.last_cycle = -1
        self.imep_first = np.nan
        self.imep_sum = 0.0
        self.mean = np.zeros((len(INDICATORS), n_cyl))
        self.m2 = np.zeros((n_cyl, len(INDICATORS), len(INDICATORS)))

    def add(self, x: np.ndarray, cycle: int, imep_pa: float) -> None:
        """Fold one cycle's indicators (4, z) (all finite: the caller checks) at mean IMEP ``imep_pa``."""
        self.n += 1
        self.first_cycle = cycle if self.first_cycle < 0 else self.first_cycle
        self.imep_first = imep_pa if self.n == 1 else self.imep_first
        self.last_cycle = cycle
        self.imep_sum += imep_pa
        d = x - self.mean
        self.mean = self.mean + d / self.n
        d2 = x - self.mean
        self.m2 += np.einsum("iz,jz->zij", d, d2)

    def band(self, width: float) -> Band:
        imep = self.imep_sum / max(self.n, 1)
        return Band(self.mean.copy(), self.m2 / max(self.n - 1, 1), self.n, self.first_cycle, self.last_cycle,
                    imep, imep * (1.0 - width), imep * (1.0 + width))

    def baseline(self, width: float) -> Baseline:
        z = self.mean.shape[1]
        nan = np.full(z, np.nan)
        return Baseline((self.band(width),), nan, nan.copy(), np.full(z, -1))
