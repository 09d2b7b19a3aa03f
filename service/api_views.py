"""What the API shows of the monitor's results, as the contract's plain dicts (service/api_models.py types them).

No figure is decided here: what a friction figure is (measured, share, prior, unresolved, withheld) comes from
``core.monitor.report.figure_status.friction_status`` through ``CycleResult.to_json``, with the window and the active flags
chosen exactly as ``frictionwatch analyze`` chooses them (service/cmd_analyze.summary, docs/results.md), so the API
never shows a prior or a share as a measurement and says the same as the analyze JSON for the same cycles.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Sequence
from dataclasses import asdict

import numpy as np
from frictionwatch.core.model.calibration import Calibration
from frictionwatch.core.monitor.report.figure_status import STATUSES, friction_status, split_flag
from frictionwatch.core.monitor.report.results import PA_PER_BAR, CycleResult
from frictionwatch.core.monitor.report.run_summary import EstimateWindow, end_of_run_status, estimate_window
from frictionwatch.service.cmd_analyze import tdc_watch_document
from frictionwatch.service.engine_service import TdcWatchView
from frictionwatch.service.window_figures import NO_PREVIOUS_CYCLE, WindowFigures, active_from_counts

RPM_PER_RAD_S = 30.0 / math.pi
FIGURE_VALUES = ("fmep_bar", "fmep_sigma_bar", "friction_torque_mean_nm", "friction_torque_sigma_nm")


def num(x: float) -> float | None:
    v = float(x)
    return v if math.isfinite(v) else None


def cycle_summary(engine_id: str, r: CycleResult) -> dict:
    """CycleSummary (contract): one cycle's measured quantities and its flags."""
    imep, pmax, _ = r.pressure_figures()  # None where the siblings' mean stands in for a flagged channel
    return {"engine_id": engine_id, "cycle_index": int(r.index), "t_start_s": num(r.t_start),
            "rpm_mean": num(r.rpm_mean), "load_torque_nm": num(r.load_torque), "load_power_kw": num(r.load_power / 1e3),
            "imep_bar": [num(v / PA_PER_BAR) for v in imep], "pmax_bar": [num(v / PA_PER_BAR) for v in pmax],
            "friction_balance_nm": num(r.friction_balance), "flags": list(r.flags)}


def _cylinder_loss(k: int, cyl: dict, names: Sequence[str], flags: frozenset[str] | Sequence[str],
                   by_cylinder: dict[int, list[str]] | None = None) -> dict:
    """CylinderLoss from one cylinder of ``CycleResult.to_json``: the figure as shown, with its status.
    ``by_cylinder``: ``flags`` already sorted by cylinder (``flags_by_cylinder``), for a caller that builds all the
    cylinders."""
    fig = cyl["friction"]
    coefs, sigmas = cyl["coefficients"], cyl["coefficients_sigma"]
    labels = list(names) if len(names) == len(coefs) else [f"term{i + 1}" for i in range(len(coefs))]
    return {"cylinder": k + 1, **{key: fig[key] for key in FIGURE_VALUES},
            "coefficients": dict(zip(labels, coefs)), "coefficient_sigmas": dict(zip(labels, sigmas)),
            "data_weight": fig["data_weight"], "status": fig["status"], "reason": fig["reason"],
            "calibration": fig["calibration"], "calibration_sigma_nm": fig["calibration_sigma_nm"],
            "flags": (by_cylinder.get(k + 1, []) if by_cylinder is not None
                      else sorted(f for f in flags if split_flag(f)[1] == k + 1))}


def flags_by_cylinder(flags: frozenset[str] | Sequence[str]) -> dict[int, list[str]]:
    """The flags of each cylinder (``<kind>_cyl<k>``, figure_status.split_flag), sorted: what ``_cylinder_loss``
    picks for cylinder k, for every cylinder in one pass over the flags."""
    out: dict[int, list[str]] = {}
    for f in sorted(flags):
        k = split_flag(f)[1]
        if k is not None:
            out.setdefault(k, []).append(f)
    return out


def values_by_status(loss: dict) -> dict:
    """A CylinderLoss with its figure's values under the name of what they are: the measurement keys
    (FIGURE_VALUES) hold a value only where the status is 'measured', as ``analyze --json``'s flat keys; a share's
    value is under ``share_*`` (null otherwise). A client that reads ``fmep_bar`` without ``status`` never takes a
    share for a measurement. (A cylinder's figure is never the prior: figure_status makes it unresolved then.)"""
    share = loss["status"] == "share"
    out = dict(loss)
    out.update({f"share_{key}": loss[key] if share else None for key in FIGURE_VALUES})
    if loss["status"] != "measured":
        out.update(dict.fromkeys(FIGURE_VALUES))
    return out


def cylinder_losses(r: CycleResult, names: Sequence[str]) -> list[dict]:
    """Each cylinder's smoothed loss as this one result reads it (its own flags): what a store keeps per cycle."""
    doc = r.to_json()
    return [values_by_status(_cylinder_loss(k, c, names, r.flags)) for k, c in enumerate(doc["cylinders"])]


def engine_figure(r: CycleResult) -> dict:
    """The engine's smoothed friction figure as this one result reads it (its own flags), for the fleet view: the
    value and its sigma only where the status is 'measured' (a prior is never shown as a measurement)."""
    fig = r.to_json()["friction"]
    measured = fig["status"] == "measured"
    return {"fmep_bar": fig["fmep_bar"] if measured else None,
            "fmep_sigma_bar": fig["fmep_sigma_bar"] if measured else None,
            "status": fig["status"], "reason": fig["reason"]}


def losses_now(engine_id: str, results: Sequence[CycleResult], names: Sequence[str]) -> dict:
    """The monitor's smoothed estimate at the newest result, over the window it stands for (cmd_analyze.summary):
    its window and active flags as ``analyze`` reads them from every result (run_summary.end_of_run_status). The
    reference the served reply (``losses_smoothed``) is held to."""
    window, active, _ = end_of_run_status(results)
    return _losses_doc(engine_id, results[-1], window, active, names)


def losses_smoothed(engine_id: str, last: CycleResult, indices: Sequence[int], weights: Sequence[float],
                    active: frozenset[str], names: Sequence[str]) -> dict:
    """``losses_now`` from the held results' cycle indices and smoothed weights (oldest first) and the flags that
    apply over the estimate's window (``active``: run_summary.active_flags's): what the API state keeps beside its
    ring (listeners.LatestState.smoothed), so a request does not walk the ring's 5000 results."""
    return _losses_doc(engine_id, last, estimate_window(indices, weights), active, names)


def _losses_doc(engine_id: str, last: CycleResult, window: EstimateWindow, active: frozenset[str],
                names: Sequence[str]) -> dict:
    doc = last.to_json(status=friction_status(last.smoothed, active), window=asdict(window))
    by_cylinder = flags_by_cylinder(active)
    eng = doc["friction"]
    return {"engine_id": engine_id, "cycle_index": int(last.index), "estimate": "smoothed",
            "window": {"first_cycle": window.first_cycle, "last_cycle": window.last_cycle,
                       "cycles": num(window.effective_cycles), "centre_cycle": window.centre_cycle,
                       "forgetting": window.forgetting},
            "engine": {**{key: eng[key] for key in FIGURE_VALUES}, "status": eng["status"], "reason": eng["reason"],
                       "calibration": eng["calibration"], "calibration_sigma_nm": eng["calibration_sigma_nm"]},
            "active_flags": sorted(active),
            "cylinders": [values_by_status(_cylinder_loss(k, c, names, active, by_cylinder))
                          for k, c in enumerate(doc["cylinders"])]}


class OwnEstimateDocuments:
    """The newest result's own-estimate document (``to_json(smoothed=False)``) under a window's active flags, made
    once per (result, flags) and shared by an engine's window requests until its API state shows a new result.

    A window reply reads its statuses from this document (``losses_window``); it was ~40 % of the route's work
    (design note 139) and the same for every window length of one cycle with the same active flags (the mix asks
    100, 1000 and 5000 cycles one after the other, ~1.2 window requests an engine a cycle at 200 req/s). Keyed by
    the result itself (held, so its identity is not reused) and the flags: a new cycle, or other flags, is a miss
    and never a stale document. The documents are shared between threads and never changed by their readers
    (``_cylinder_loss`` and ``losses_window`` build new dicts). One lock-free swap: two threads that miss at once
    both make the same document."""

    def __init__(self) -> None:
        self._held: tuple[CycleResult | None, dict[frozenset[str], dict]] = (None, {})
        self.made = 0  # documents made (misses), for a test and a bench

    def get(self, last: CycleResult, active: frozenset[str]) -> dict:
        result, docs = self._held
        if result is not last:
            result, docs = last, {}
            self._held = (result, docs)
        doc = docs.get(active)
        if doc is None:
            doc = docs[active] = last.to_json(smoothed=False, status=friction_status(last.cycle, active))
            self.made += 1
        return doc


class NewestReplies:
    """One engine's replies made from its newest result, each made once a cycle and shared by the requests that
    ask for it (the API's one per-engine cache): the smoothed ``/losses`` reply, rendered, by cycle index (made by
    one request while any other caller waits for it: the routes run on the event loop since design note 154, a
    caller on another thread still may), the window replies, rendered, by the API state's count of
    results and the window's length in cycles (``window``), and the own-estimate documents the window replies read
    their statuses from (``own``: by result and active flags)."""

    def __init__(self) -> None:
        self._smoothed: tuple[int, bytes] | None = None
        self._making = threading.Lock()
        self._windows: tuple[int | None, dict[int, bytes]] = (None, {})
        self.windows_made = 0  # window replies made (misses), for a test and a bench
        self.own = OwnEstimateDocuments()

    def window(self, version: int, cycles: int, make: Callable[[], bytes]) -> bytes:
        """The window reply of ``cycles`` cycles as of the API state's ``version`` (LatestState.versioned_window:
        its count of results taken in), made by ``make()`` when not held. A window asked for more cycles than are
        held is the window of all of them: the cycles it was made for, not those asked, are the key, so a dashboard's
        (or the mix's) 1000- and 5000-cycle windows share one reply until 1000 cycles are held. Another version
        starts afresh. One lock-free swap: two threads that miss at once both make the same reply."""
        held, replies = self._windows
        if held != version:
            replies = {}
            self._windows = (version, replies)
        got = replies.get(cycles)
        if got is None:
            got = replies[cycles] = make()
            self.windows_made += 1
        return got

    def smoothed(self, index: int, make: Callable[[], tuple[int, bytes]]) -> bytes:
        """The smoothed reply of cycle ``index`` or a newer one; ``make()`` -> (its cycle index, its bytes) when
        none is held."""
        hit = self._smoothed
        if hit is None or hit[0] != index:
            with self._making:
                hit = self._smoothed
                if hit is None or hit[0] < index:  # not made by the request this one waited for
                    hit = self._smoothed = make()
        return hit[1]


def losses_window(engine_id: str, last: CycleResult, win: WindowFigures, names: Sequence[str],
                  holes: Sequence[dict] = (), documents: OwnEstimateDocuments | None = None) -> dict:
    """Each cylinder's per-cycle friction (each cycle's own estimate) averaged over the window ``win`` (its figures:
    service/window_figures.py), with the 1-sigma of the mean from the cycle-to-cycle scatter. ``last``: the result
    the statuses are read from, the window's newest cycle with a previous cycle (LatestState.window).

    Cycles without a previous cycle (a log's first, each loop seam of a replay, a stream restart) have no estimate of
    their own: left out of the means and said (``window.cycles_left_out``), not a reason to call the window
    unresolved. A mean is given only where every other cycle of the window shows the figure with the same status
    (all measured, or all shares); otherwise the status of the window is ``last``'s with the active flags, or
    'unresolved' saying how many cycles measured it.

    A window spans ``first_cycle`` .. ``last_cycle``; indices in it with no result (skipped, or in ``holes``: dropped
    while the analysis was behind, service/stream_holes.py) are counted and said (``cycles_missing``,
    ``cycles_dropped``, ``missing``): the means stand for the cycles analysed, not for the whole span.
    ``documents``: the engine's shared ``last`` documents (``OwnEstimateDocuments``); None makes one here."""
    n_cycles, n_counted, lay = win.cycles, win.counted, win.layout
    # active_flags (run_summary) over the window, from the window's counts: the newest cycle's and the frequent ones;
    # no_previous_cycle is not one of them: those cycles are out of the figures, counted in cycles_left_out
    active = active_from_counts(last.flags, win.flag_counts, n_cycles) - {NO_PREVIOUS_CYCLE}
    status = (documents or OwnEstimateDocuments()).get(last, frozenset(active))
    mep_per_nm = last.mep_per_nm() / PA_PER_BAR  # bar per N m of one cylinder
    left = _left_out_words(win.left_out)
    # the figures as Python numbers, once (win.stat and num per value were ~2/3 of the view's work, design note 154)
    means, sems, counts = win.mean.tolist(), win.sem.tolist(), win.count.tolist()
    mean_nums, sem_nums = [num(v) for v in means], [num(v) for v in sems]
    status_counts, by_cylinder = win.status_counts.tolist(), flags_by_cylinder(active)
    cylinders = []
    for k, cyl in enumerate(status["cylinders"]):
        loss = _cylinder_loss(k, cyl, names, active, by_cylinder)
        kinds = status_counts[k]
        if n_counted == 0:
            loss.update(dict.fromkeys(FIGURE_VALUES), status="unresolved", data_weight=None,
                        reason=f"no cycle of the window has its own estimate ({left})")
        elif loss["status"] in ("withheld", "unresolved"):
            pass  # the newest counted cycle's status with the window's flags: no value
        elif kinds[STATUSES.index(loss["status"])] == n_counted:
            # the scatter's sem knows nothing of the calibration, whose error is the same in every cycle: added back
            cal = loss["calibration_sigma_nm"] or 0.0
            for key, sigma_key, per_nm, col in (("friction_torque_mean_nm", "friction_torque_sigma_nm", 1.0, lay.torque(k)),
                                                ("fmep_bar", "fmep_sigma_bar", mep_per_nm, lay.fmep(k))):
                mean, sem, n = means[col], sems[col], counts[col]
                loss[key], loss[sigma_key] = num(mean), (num(math.hypot(sem, cal * per_nm)) if n > 1
                                                         else loss[sigma_key])
            col = lay.weight(k)
            loss["data_weight"] = means[col] if counts[col] else None
            labels = list(loss["coefficients"])
            first = lay.coef(k, 0)
            loss["coefficients"] = dict(zip(labels, mean_nums[first:first + len(labels)]))
            loss["coefficient_sigmas"] = dict(zip(labels, sem_nums[first:first + len(labels)]))
        else:
            n_measured = kinds[STATUSES.index("measured")]
            loss.update(dict.fromkeys(FIGURE_VALUES), status="unresolved",
                        reason=f"the figure's status changed within the window (measured in {n_measured} of "
                               f"{n_counted} cycles{'; ' + left if win.left_out else ''}): no mean over the "
                               "window; see the estimate without a window")
        cylinders.append(values_by_status(loss))
    eng_mean, eng_sem, n = win.stat(0)
    eng_cal = status["friction"]["calibration_sigma_nm"] or 0.0
    eng_sem = math.hypot(eng_sem, eng_cal * mep_per_nm / last.n_cyl)
    whole = n_counted > 0 and n == n_counted
    return {"engine_id": engine_id, "cycle_index": win.last_cycle, "estimate": "window",
            "window": {"first_cycle": win.first_cycle, "last_cycle": win.last_cycle, "cycles": n_counted,
                       "cycles_left_out": win.left_out, "left_out": left if win.left_out else None,
                       **missing_in_window(win, holes)},
            "engine": {"fmep_bar": num(eng_mean) if whole else None,
                       "fmep_sigma_bar": num(eng_sem) if whole else None,
                       "status": "measured" if whole else "unresolved",
                       "calibration": status["friction"]["calibration"],
                       "calibration_sigma_nm": num(eng_cal) if whole else None,
                       "reason": None if whole else f"the engine's friction was measured in {n} of {n_counted} "
                                                    f"cycles of the window{'; ' + left if win.left_out else ''}"},
            "active_flags": sorted(active), "cylinders": cylinders}


def missing_in_window(win: WindowFigures, holes: Sequence[dict]) -> dict:
    """The window's cycle indices without a result, and those of them dropped while behind, counted and in words."""
    missing = max(0, win.last_cycle - win.first_cycle + 1 - win.cycles)
    spans = [(max(h["first_cycle"], win.first_cycle), min(h["last_cycle"], win.last_cycle)) for h in holes]
    dropped = min(missing, sum(b - a + 1 for a, b in spans if b >= a))
    words = None
    if missing:
        where = ", ".join(f"{a}-{b}" if b > a else f"{a}" for a, b in spans if b >= a)
        words = (f"{missing} cycle{'' if missing == 1 else 's'} of cycles {win.first_cycle}-{win.last_cycle} not "
                 "analysed" + (f": {dropped} dropped while the analysis was behind (cycles {where})" if dropped else "")
                 + (f"{',' if dropped else ':'} {missing - dropped} skipped" if missing > dropped else ""))
    return {"cycles_missing": missing, "cycles_dropped": dropped, "missing": words}


def _left_out_words(n: int) -> str:
    return f"{n} cycle{'' if n == 1 else 's'} without a previous cycle left out"


def friction_torque(r: CycleResult) -> dict:
    """The newest whole result's friction torque vs crank angle (engine total and per cylinder)."""
    if r.grid is None or r.friction_torque is None:
        raise LookupError("the newest result carries no traces")
    cyl = r.friction_torque_cyl
    return {"cycle_index": int(r.index), "crank_angle_deg": np.degrees(r.grid).tolist(),
            "friction_torque_nm": _finite_list(r.friction_torque),
            "friction_torque_cyl_nm": [] if cyl is None else [_finite_list(row) for row in cyl]}


def speed(r: CycleResult, history: Sequence[CycleResult]) -> dict:
    """The newest whole result's measured and model flywheel speed [rpm] on the crank-angle grid, and the mean speed
    of the recent cycles."""
    if r.grid is None or r.speed_measured is None or r.speed_model is None:
        raise LookupError("the newest result carries no traces")
    return {"cycle_index": int(r.index), "crank_angle_deg": np.degrees(r.grid).tolist(),
            "speed_measured_rpm": _finite_list(r.speed_measured * RPM_PER_RAD_S),
            "speed_model_rpm": _finite_list(r.speed_model * RPM_PER_RAD_S),
            "history": {"cycle_index": [int(h.index) for h in history], "rpm_mean": [num(h.rpm_mean) for h in history]}}


def sensor_health(r: CycleResult, watch: TdcWatchView, cal: Calibration, n_cyl: int) -> dict:
    """SensorHealth (contract): what checks the sensors on this engine, as of the newest result ``r``.

    ``tdc_watch``: the TDC found from each cylinder's pressure every ``window_cycles`` cycles (on by default,
    core.monitor.calibration.tdc_watch; the same block as ``analyze --json``'s ``tdc_from_pressure``, with the
    cylinders numbered, the cycle that closed the window and the cycles gathered towards the next one).
    ``calibration``: the model's calibration section (core.model.calibration) every friction sigma carries, with
    each of the ``n_cyl`` cylinders' own TDC and gain sigmas.
    ``enabled`` and the keys beside it: the speed-based sensor-health stage (core.monitor.checks.sensor_health), opt-in
    (``serve --sensor-health``); ``cylinders`` empty and its figures null when it is off. ``flags``: every
    ``sensor_*`` flag of the newest cycle, whichever check raised it (each withholds the figures it touches)."""
    flags = sorted(f for f in r.flags if split_flag(f)[0].startswith("sensor_"))
    stage = r.sensor_health.to_json() if r.sensor_health is not None else None
    own = cal.own_variances(n_cyl)
    doc = tdc_watch_document(watch.state)
    cylinders = [] if doc is None else [
        {"cylinder": k + 1, "offset_deg": None, "sigma_deg": None, "method": None} if c is None
        else {"cylinder": k + 1, **c} for k, c in enumerate(doc["cylinders"])]
    return {
        "cycle_index": int(r.index),
        "enabled": stage is not None,
        "flags": flags,
        "cylinders": [] if stage is None else stage["cylinders"],
        "wheel_tdc_offset_deg": None if stage is None else stage["wheel_tdc_offset_deg"],
        "wheel_tdc_offset_sigma_deg": None if stage is None else stage["wheel_tdc_offset_sigma_deg"],
        "friction_sigma_nm": None if stage is None else stage["friction_sigma_nm"],
        "speed_based_flags": [] if stage is None else list(stage["flags"]),
        "tdc_watch": {
            "window_cycles": watch.window_cycles,
            "cycles_gathered": int(watch.state.cycles),
            "window_last_cycle": watch.window_cycle,
            "wheel_offset_deg": None if doc is None else doc["wheel_offset_deg"],
            "wheel_sigma_deg": None if doc is None else doc["wheel_sigma_deg"],
            "flags": [] if doc is None else doc["flags"],
            "cylinders": cylinders,
        },
        "calibration": {
            "status": cal.status, "source": cal.source,
            "tdc_wheel_sigma_deg": cal.tdc_wheel_sigma_deg, "tdc_cylinder_sigma_deg": cal.tdc_cylinder_sigma_deg,
            "gain_sigma_pct": 100.0 * cal.gain_sigma, "gain_common_sigma_pct": 100.0 * cal.gain_common_sigma,
            "tdc_cylinder_sigmas_deg": np.degrees(np.sqrt(own[0])).tolist(),
            "gain_sigmas_pct": (100.0 * np.sqrt(own[1])).tolist(),
            "inertia_sigma_pct": 100.0 * cal.inertia_sigma,
            "load_torque_sigma_pct": 100.0 * cal.load_torque_sigma,
            "load_power_sigma_pct": 100.0 * cal.load_power_sigma,
            "generator_efficiency": cal.generator_efficiency,
        },
    }


def _finite_list(a: np.ndarray) -> list[float | None]:
    """The values as Python floats, None where not finite. One ``tolist`` (C) and a pass only where a value is not
    finite: a float per element through ``num`` made the friction-torque reply's view ~1.6 ms (21 traces)."""
    arr = np.asarray(a, dtype=float)
    out = arr.tolist()
    if not np.isfinite(arr).all():
        out = [v if math.isfinite(v) else None for v in out]
    return out
