"""Tooth-spacing error learned on-line (physics.md §14.3), with explicit state in and out.

Model. Tooth j (wheel index 0..T-1, 0 = first after the gap) sits at theta_j = 2 pi j / N + eps_j, sum eps_j = 0.
At constant speed the fraction of a revolution's time spent between edges is the fraction of its angle, so for one
revolution from edge s: d_i = 2 pi F_i - nu_i = eps_{s+i} - eps_s, with F_i the cumulative time fraction and nu_i the
nominal angle from edge s. d is stored by wheel index with its mean removed (so eps_s drops out).

What else is in d, and how it is removed:
- the engine's own speed ripple. It is 4 pi periodic; every cycle gives two revolutions covering it exactly
  (edges 0..T and T..2T of the assembled cycle), so the half orders cancel in the sum and only integer orders stay.
  Those are removed by a least-squares fit in tooth angle: always the orders ``remove_orders`` (low orders, where
  runout also lives); an order of ``engine_orders`` (firing-order multiples, z/2 per revolution for a 4-stroke)
  when its power exceeds ``engine_factor`` times the median order power; any other order when it exceeds
  ``auto_factor`` times that median (eps is nearly white, a speed line is not). What is removed is unobservable
  from one operating point: ``correction`` returns eps without those orders, ``removed_orders`` says which.
  Low orders cost little: a tooth error changes the speed by d eps / d theta, so its effect grows with order;
  removing a high order that held only eps costs much, hence the high default thresholds (8x: a pure-eps order
  passes it with probability 2^-8). An engine line within a few times the eps level at its order stays in eps.
  On the plant simulator (120 cycles, sigma 0.03 deg): k9k-4cyl finds orders 4 and 6 (2 is always removed) and
  keeps 15 % of the wheel's speed error; genset-v20, whose ripple is far below its tooth error, keeps 0.6 %.
- a slow speed drift: a linear speed change a (per revolution) adds (a / 4 pi) nu (2 pi - nu). a is taken from the
  mean speeds of consecutive cycles (not from the two revolutions of one cycle, which differ by the half orders) and
  subtracted; cycles with |a| > ``max_drift`` are not used (not steady).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numba
import numpy as np

TWO_PI = 2.0 * np.pi


@dataclass(frozen=True)
class SpacingState:
    """sum_d (T,) weighted sum of per-revolution deviations [rad]; sum_d2 (T,) of their squares; weight; revs used;
    prev_end_tick / prev_omega: end and mean speed of the last cycle seen (for the drift); skipped: cycles refused."""

    sum_d: np.ndarray
    sum_d2: np.ndarray
    weight: float = 0.0
    revs: int = 0
    prev_end_tick: int = -1
    prev_omega: float = 0.0
    skipped: int = 0


@numba.njit(cache=True)
def _rev_deviation(ticks, index, start, n, k, drift, out):
    """d by wheel index for the revolution from edge ``start`` (T+1 edges), drift-corrected, mean removed."""
    t = n - k
    pitch = TWO_PI / n
    total = float(ticks[start + t] - ticks[start])
    nu = 0.0
    s = 0.0
    for i in range(t):
        f = float(ticks[start + i] - ticks[start]) / total
        d = TWO_PI * f - nu - drift / (4.0 * np.pi) * nu * (TWO_PI - nu)
        out[index[start + i]] = d
        s += d
        nu += pitch * (k + 1 if index[start + i] == t - 1 else 1)
    mean = s / t
    for j in range(t):
        out[j] -= mean


def rev_deviation(tooth_ticks: np.ndarray, tooth_index: np.ndarray, start: int, wheel_teeth: int, wheel_missing: int,
                  drift: float = 0.0) -> np.ndarray:
    """Per-revolution angle deviation d (T,) [rad] by wheel index, for the revolution starting at edge ``start``.

    tooth_ticks (n,) int64, tooth_index (n,) int64 wheel index of each edge (consecutive teeth); drift: relative
    speed change over the revolution."""
    ticks = np.ascontiguousarray(tooth_ticks, dtype=np.int64)
    idx = np.ascontiguousarray(tooth_index, dtype=np.int64)
    t = wheel_teeth - wheel_missing
    if start < 0 or start + t >= ticks.shape[0] + 0 or idx.shape != ticks.shape:
        raise ValueError(f"a revolution needs edges {start}..{start + t}; got {ticks.shape[0]} edges")
    if idx[start + t] != idx[start] or np.any(np.diff(idx[start: start + t + 1]) % t != 1):
        raise ValueError("tooth_index must run through every tooth once per revolution")
    out = np.empty(t)
    _rev_deviation(ticks, idx, int(start), int(wheel_teeth), int(wheel_missing), float(drift), out)
    return out


class ToothSpacingLearner:
    """Learns eps_j from assembled cycles at steady speed. Hyper-parameters here; state is a ``SpacingState``.

    Parameters
    ----------
    wheel_teeth, wheel_missing : N positions, k missing
    remove_orders : integer orders (per revolution) always removed (runout, low-order engine content)
    engine_orders : orders where the engine's ripple may lie, e.g. ``engine_orders(z, T // 2)``
    engine_factor : remove an engine order whose power exceeds this times the median order power
    auto_factor : remove any other order whose power exceeds this times the median order power (0: off)
    forgetting : weight factor per cycle (1: plain average)
    max_drift : largest relative speed change per revolution of a usable cycle
    """

    def __init__(self, wheel_teeth: int, wheel_missing: int, remove_orders: tuple[int, ...] = (1, 2, 3),
                 engine_orders: tuple[int, ...] = (), engine_factor: float = 8.0, auto_factor: float = 10.0,
                 forgetting: float = 1.0, max_drift: float = 0.01):
        self.n, self.k = int(wheel_teeth), int(wheel_missing)
        self.t = self.n - self.k
        if self.k < 1 or self.t < 8:
            raise ValueError(f"wheel {self.n}-{self.k}: need a gap and at least 8 teeth")
        if not 0 < forgetting <= 1:
            raise ValueError("forgetting must be in (0, 1]")
        top = self.t // 2 - 1
        self.fixed = tuple(sorted({int(o) for o in remove_orders if 1 <= int(o) <= top}))
        self.engine = tuple(sorted({int(o) for o in engine_orders if 1 <= int(o) <= top} - set(self.fixed)))
        self.engine_factor = float(engine_factor)
        self.auto_factor = float(auto_factor)
        self.forgetting = float(forgetting)
        self.max_drift = float(max_drift)
        self.angle = np.arange(self.t) * (TWO_PI / self.n)  # nominal angle of tooth j from tooth 0
        self._orders = np.arange(1, top + 1)

    def initial(self) -> SpacingState:
        return SpacingState(np.zeros(self.t), np.zeros(self.t))

    def update(self, state: SpacingState, tooth_ticks: np.ndarray, tooth_index: np.ndarray) -> SpacingState:
        """Fold in one assembled cycle (``Cycle.tooth_ticks``, ``Cycle.tooth_index``): its two revolutions."""
        ticks = np.ascontiguousarray(tooth_ticks, dtype=np.int64)
        idx = np.ascontiguousarray(tooth_index, dtype=np.int64)
        t = self.t
        if ticks.shape[0] < 2 * t + 1 or idx.shape != ticks.shape:
            raise ValueError(f"a cycle needs at least {2 * t + 1} edges, got {ticks.shape[0]}")
        span = float(ticks[2 * t] - ticks[0])
        omega = 2.0 * TWO_PI / span  # rad per tick, mean over exactly 4 pi
        consecutive = state.prev_end_tick >= 0 and abs(int(ticks[0]) - state.prev_end_tick) < 0.01 * span
        drift = 0.5 * (omega - state.prev_omega) / omega if consecutive else 0.0
        nxt = replace(state, prev_end_tick=int(ticks[2 * t]), prev_omega=omega)
        if abs(drift) > self.max_drift:
            return replace(nxt, skipped=state.skipped + 1)
        d = np.empty(t)
        sum_d = state.sum_d * self.forgetting
        sum_d2 = state.sum_d2 * self.forgetting
        for start in (0, t):
            if np.any(np.diff(idx[start: start + t + 1]) % t != 1):
                raise ValueError("tooth_index must run through every tooth once per revolution")
            _rev_deviation(ticks, idx, start, self.n, self.k, drift, d)
            sum_d = sum_d + d
            sum_d2 = sum_d2 + d * d
        return replace(nxt, sum_d=sum_d, sum_d2=sum_d2, weight=state.weight * self.forgetting + 2.0,
                       revs=state.revs + 2)

    def mean_deviation(self, state: SpacingState) -> np.ndarray:
        if state.weight <= 0:
            return np.zeros(self.t)
        return state.sum_d / state.weight

    def _fit(self, d: np.ndarray, orders) -> np.ndarray:
        """d less its least-squares fit of a constant and the given orders (tooth angles are not uniform: gap)."""
        cols = [np.ones(self.t)]
        for o in sorted(orders):
            cols += [np.cos(o * self.angle), np.sin(o * self.angle)]
        basis = np.stack(cols, axis=1)
        coef, *_ = np.linalg.lstsq(basis, d, rcond=None)
        return d - basis @ coef

    def removed_orders(self, state: SpacingState) -> tuple[int, ...]:
        """Orders projected out: the fixed ones, then greedily the strongest order still standing out of the
        spectrum of the residual (engine orders at ``engine_factor``, others at ``auto_factor`` times the median
        power). One at a time, refitting in between, because a strong line leaks into every other order through
        the gap in the tooth angles."""
        orders = set(self.fixed)
        if state.weight <= 0:
            return tuple(sorted(orders | set(self.engine)))
        d = self.mean_deviation(state)
        ph = np.outer(self._orders, self.angle)
        cos, sin = np.cos(ph), np.sin(ph)
        is_engine = np.isin(self._orders, self.engine)
        factor = np.where(is_engine, self.engine_factor, self.auto_factor if self.auto_factor > 0 else np.inf)
        while True:
            r = self._fit(d, orders)
            power = (cos @ r) ** 2 + (sin @ r) ** 2
            free = ~np.isin(self._orders, list(orders))
            rest = free & ~is_engine
            if rest.sum() < 4:
                return tuple(sorted(orders))
            level = np.median(power[rest])
            score = np.where(free, power / (factor * level), 0.0)
            best = int(np.argmax(score))
            if score[best] <= 1.0:
                return tuple(sorted(orders))
            orders.add(int(self._orders[best]))

    def correction(self, state: SpacingState) -> np.ndarray:
        """eps (T,) [rad] by wheel index: the mean deviation less a least-squares fit of a constant and the removed
        orders; sum zero. Zeros before any cycle was used."""
        eps = self._fit(self.mean_deviation(state), self.removed_orders(state))
        return eps - eps.mean()

    def uncertainty(self, state: SpacingState) -> np.ndarray:
        """1-sigma standard error of the mean deviation per tooth [rad] (revolution-to-revolution scatter)."""
        if state.revs < 2:
            return np.full(self.t, np.inf)
        mean = state.sum_d / state.weight
        var = np.maximum(state.sum_d2 / state.weight - mean**2, 0.0)
        return np.sqrt(var / state.revs)


def engine_orders(n_cyl: int, max_order: int, strokes: int = 4) -> tuple[int, ...]:
    """Integer orders per revolution where a balanced engine's speed ripple lies: multiples of the firing frequency
    (z / 2 per revolution for a 4-stroke; integer multiples only, the half orders cancel over a cycle)."""
    base = n_cyl * 2.0 / strokes
    out = []
    mult = 1
    while mult * base <= max_order:
        v = mult * base
        if abs(v - round(v)) < 1e-9:
            out.append(round(v))
        mult += 1
    return tuple(out)
