"""A small analytic engine stream for the assembler and speed tests (no physics beyond what the tests need).

Crank angle is given in time, theta(t) = theta0 + Omega t + a_d t^2 / 2 + sum_i b_i sin(w_i t + phi_i), so tooth edge
times are exact (Newton on theta(t) = edge angle) and omega(t) is known in closed form. The ripple frequencies are
multiples of the cycle frequency Omega/2 ("orders" n: w = n Omega), so at constant speed the motion is 4 pi periodic.

Pressure of cylinder k: 1 bar + a Gaussian firing peak at its firing TDC phi_k (60 bar, 25 deg wide) and a small
compression-only bump is deliberately absent at gas-exchange TDC, so the firing TDC is unambiguous (physics.md §14.5).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from frictionwatch.core.types import AcquisitionInfo, CamBatch, LoadSample, PressureBlock, StreamRecord, ToothBatch


@dataclass
class Motion:
    """theta(t) [rad, cyl-1 convention, unwrapped]; ``orders``/``amps``/``phases``: ripple as omega amplitude."""

    rpm: float
    orders: tuple[float, ...] = (2.0, 4.0, 0.5)
    amps: tuple[float, ...] = (0.02, 0.005, 0.002)  # relative speed amplitude per order
    phases: tuple[float, ...] = (0.3, 1.1, -0.4)
    accel: float = 0.0  # rad/s^2 mean angular acceleration
    theta0: float = 0.1

    @property
    def omega(self) -> float:
        return self.rpm * 2 * np.pi / 60.0

    def theta(self, t):
        w = self.omega
        out = self.theta0 + w * t + 0.5 * self.accel * t * t
        for n, a, p in zip(self.orders, self.amps, self.phases):
            wn = n * w
            out = out + (a * w / wn) * (np.sin(wn * t + p) - np.sin(p))
        return out

    def speed(self, t):
        w = self.omega
        out = w + self.accel * t + 0 * t
        for n, a, p in zip(self.orders, self.amps, self.phases):
            out = out + a * w * np.cos(n * w * t + p)
        return out

    def time_of(self, theta):
        """Invert theta(t) by Newton (vectorised); exact to ~1e-15 s."""
        theta = np.asarray(theta, dtype=np.float64)
        t = (theta - self.theta0) / self.omega
        for _ in range(40):
            f = self.theta(t) - theta
            t = t - f / self.speed(t)
            if np.max(np.abs(f), initial=0.0) < 1e-13:
                break
        return t


@dataclass
class AngleMotion:
    """omega(theta) = Omega (1 + slope theta) (1 + sum a_i cos(n_i theta + phi_i)): a ripple locked to the crank angle
    (as combustion is) on a linearly rising speed. t(theta) by cumulative Simpson on a 1e-3 rad grid and cubic
    Hermite in between (error far below a 10 MHz tick)."""

    rpm: float
    orders: tuple[float, ...] = (2.0, 4.0, 0.5)
    amps: tuple[float, ...] = (0.02, 0.005, 0.002)
    phases: tuple[float, ...] = (0.3, 1.1, -0.4)
    slope: float = 0.0  # relative speed rise per rad
    theta_end: float = 200.0

    def __post_init__(self):
        from scipy.integrate import cumulative_simpson
        from scipy.interpolate import CubicHermiteSpline

        th = np.arange(-1.0, self.theta_end, 1e-3)
        w = self.speed_at(th)
        t = cumulative_simpson(1.0 / w, x=th, initial=0.0)
        t -= np.interp(0.0, th, t)
        self._t_of = CubicHermiteSpline(th, t, 1.0 / w)
        self._th_of = CubicHermiteSpline(t, th, w)

    @property
    def omega(self) -> float:
        return self.rpm * 2 * np.pi / 60.0

    def speed_at(self, theta):
        out = self.omega * (1.0 + self.slope * np.asarray(theta, dtype=np.float64))
        rip = 1.0
        for n, a, p in zip(self.orders, self.amps, self.phases):
            rip = rip + a * np.cos(n * theta + p)
        return out * rip

    def time_of(self, theta):
        return self._t_of(np.asarray(theta, dtype=np.float64))

    def theta(self, t):
        return self._th_of(np.asarray(t, dtype=np.float64))

    def speed(self, t):
        return self.speed_at(self.theta(t))


@dataclass
class Stream:
    n_teeth: int = 60
    n_missing: int = 2
    first_tooth_deg: float = -84.0
    tick_hz: float = 10e6
    cam_deg: float | None = 100.0
    firing_deg: tuple[float, ...] = (0.0, 540.0, 180.0, 360.0)
    pressure_cyl: tuple[int, ...] = (1, 2, 3, 4)
    pressure_hz: float = 20e3
    eps: np.ndarray | None = None  # (N - k,) tooth angle errors [rad]
    batch_s: float = 0.004
    load_hz: float = 50.0
    extra: dict = field(default_factory=dict)

    def info(self) -> AcquisitionInfo:
        return AcquisitionInfo(self.tick_hz, self.n_teeth, self.n_missing, self.first_tooth_deg, self.cam_deg,
                               tuple(self.pressure_cyl))

    def edge_angles(self, theta_end: float) -> tuple[np.ndarray, np.ndarray]:
        """True angles of all edges from 0 to theta_end (with eps) and their wheel index."""
        n, t = self.n_teeth, self.n_teeth - self.n_missing
        pitch = 2 * np.pi / n
        a0 = np.radians(self.first_tooth_deg) % (2 * np.pi) - 2 * np.pi
        revs = int(np.ceil(theta_end / (2 * np.pi))) + 2
        j = np.tile(np.arange(t), revs)
        r = np.repeat(np.arange(revs), t)
        ang = a0 + r * 2 * np.pi + j * pitch
        if self.eps is not None:
            ang = ang + self.eps[j]
        keep = (ang >= 0) & (ang <= theta_end)
        return ang[keep], j[keep]

    def pressure(self, theta: np.ndarray, cyl: int) -> np.ndarray:
        phi = np.radians(self.firing_deg[cyl - 1])
        x = (theta - phi + 2 * np.pi) % (4 * np.pi) - 2 * np.pi
        return 1e5 + 60e5 * np.exp(-((x / np.radians(25.0)) ** 2))

    def records(self, motion: Motion, duration_s: float, seed: int = 0) -> list[StreamRecord]:
        """All records in time order, cut in batches of ``batch_s`` (teeth, cam, pressure blocks, load)."""
        rng = np.random.default_rng(seed)
        theta_end = motion.theta(duration_s)
        ang, _ = self.edge_angles(theta_end)
        tt = np.round(motion.time_of(ang) * self.tick_hz).astype(np.int64)
        cam = np.array([], dtype=np.int64)
        if self.cam_deg is not None:
            c = np.radians(self.cam_deg) + 4 * np.pi * np.arange(int(theta_end / (4 * np.pi)) + 2)
            c = c[(c > 0) & (c < theta_end)]
            cam = np.round(motion.time_of(c) * self.tick_hz).astype(np.int64)
        period = self.tick_hz / self.pressure_hz
        ns = int(duration_s * self.pressure_hz)
        ts = np.arange(ns) * period
        th_s = motion.theta(ts / self.tick_hz)
        pres = {c: self.pressure(th_s, c) for c in self.pressure_cyl}
        out: list[tuple[float, int, StreamRecord]] = []
        nb = int(np.ceil(duration_s / self.batch_s))
        bt = self.batch_s * self.tick_hz
        for b in range(nb):
            lo, hi = b * bt, (b + 1) * bt
            sel = tt[(tt >= lo) & (tt < hi)]
            if sel.size:
                out.append((hi, 0, ToothBatch(sel)))
            cs = cam[(cam >= lo) & (cam < hi)]
            if cs.size:
                out.append((hi, 1, CamBatch(cs)))
            i0, i1 = int(np.ceil(lo / period)), min(int(np.ceil(hi / period)), ns)
            if i1 > i0:
                for c in self.pressure_cyl:
                    out.append((hi, 2, PressureBlock(c, round(i0 * period), period, pres[c][i0:i1].copy())))
        nl = int(duration_s * self.load_hz)
        for i in range(nl):
            tk = int(i * self.tick_hz / self.load_hz)
            out.append((tk + 1, 3, LoadSample(tk, 1000.0 + rng.normal(0, 1.0), 1.5e5)))
        out.sort(key=lambda x: (x[0], x[1]))
        return [r for _, _, r in out]
