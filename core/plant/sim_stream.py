"""A simulation run stretch by stretch: ``Simulation.chunks()`` integrates the plant set up by
``core.plant.simulate.start_simulation`` a few cycles at a time and hands each stretch over as a ``SimChunk``
(stream records in arrival order, the truth entries of the cycles it completed), keeping only the state that carries
into the next stretch: the plant's, the sensor streams' (core.plant.sim_records) and the truth's running sums
(core.plant.sim_truth). Memory is one chunk's worth whatever the number of cycles; the records and truth do not
depend on the chunk size.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import numpy as np
from frictionwatch.core.model.effects import SensorSetup
from frictionwatch.core.model.engine_model import EngineModel
from frictionwatch.core.model.thermo import charge_pressures
from frictionwatch.core.plant.plant import S_WHEEL_OFF
from frictionwatch.core.plant.sim_records import SensorRecords, acquisition_info
from frictionwatch.core.plant.sim_run import PlantRun
from frictionwatch.core.plant.sim_truth import TruthAccumulator
from frictionwatch.core.types import StreamRecord

SETTLE_A_CYCLES = 6  # governed settle (dyno law re-tuned per cycle; grid mode damped), deterministic combustion
SETTLE_B_CYCLES = 1  # final load law, combustion variability on (half a cycle, then one lead-in revolution)
# A speed step (a load step with an rpm): the dyno holds the new speed as a speed-controlled one does (time constant
# SPEED_TAU_CYCLES cycles) for SPEED_HOLD_CYCLES whole cycles (e^-5: 0.7 % of the step left), then its eddy-current
# law again, carrying the engine's torque there. Design choices for a log at two speeds, not tuned: the held law
# damps the shaft line's ripple (k9k's order-2 resonance at 1800 rpm read 24-37 rpm in held cycles, 1-5 at the
# point), so the hold is short enough that its load still jumps from cycle to cycle in nearly every held cycle,
# which the workflow leaves out (core.discrepancy.residuals.operating_groups)
SPEED_TAU_CYCLES = 1.0
SPEED_HOLD_CYCLES = 5
CHUNK_CYCLES = 8  # output cycles per hand-over: genset-v20 about 1.4 MB of records and events per cycle


@dataclass(frozen=True)
class StageSwitches:
    """A change mid-run (an effect's ``from_cycle``): from output cycle ``onsets[i]`` on the plant runs with the
    loss coefficients ``coefficients[i]`` (z, L) and the leak areas ``leaks[i]`` (z,) m^2, the true firing angles
    ``phases[i]`` (z,) rad, and the acquisition with ``sensors[i]`` (its wheel offset, the channels' gains and
    pegging); ``onsets[0]`` = 0. The phases and sensors may be left empty (no such change)."""

    onsets: list[int]
    coefficients: list[np.ndarray]
    leaks: list[np.ndarray]
    phases: list[np.ndarray] = field(default_factory=list)
    sensors: list[SensorSetup] = field(default_factory=list)

    def coefficients_of(self, cycles: np.ndarray) -> np.ndarray:
        """(n, z, L): the coefficients each of the output ``cycles`` ran with."""
        return np.stack(self.coefficients)[np.searchsorted(self.onsets, cycles, side="right") - 1]


@dataclass
class SimChunk:
    """One stretch of a run: the records releasable so far (in arrival order, continuing the previous chunk's), the
    truth entries of the output cycles completed in it, and its diagnostics (arrays of this stretch, see SimResult)."""

    records: list[StreamRecord]
    cycles: list[dict]
    diagnostics: dict


class Simulation:
    """A run set up by ``start_simulation``: ``info`` (what the acquisition states) is known at once; ``chunks()``
    integrates it (once), and when its last chunk is out ``truth`` holds the per-run truth without its "cycles"."""

    def __init__(self, model: EngineModel, run: PlantRun, *, cycles: int, steps: list, point: Callable,
                 theta_start: float, operating: dict, request: dict, sensors: SensorSetup,
                 rngs: list[np.random.Generator], stages: StageSwitches | None = None):
        """run: the plant set up at theta_start, not yet advanced; steps: [(time_s, load fraction or None for the
        coast-down[, rpm: a speed step])], in time order; point(fraction, omega)
        -> (fuel kg, brake torque estimate N m, per-cylinder means); operating: the truth's "operating" block (its
        load law and steps are filled in by the run); request: rpm, load, seed as asked (repeated in the truth)."""
        self.model, self.run, self.cycles, self.steps, self.point = model, run, cycles, steps, point
        self.theta_start, self.operating, self.request = theta_start, operating, request
        self.sensors, self.rngs = sensors, rngs
        self.stages = stages
        self.second_wheel = run.wheel2 is not None
        self.info = acquisition_info(model.spec, self.second_wheel)
        self.truth: dict | None = None
        self._started = False
        self._state: _RunState | None = None  # set by the settling or by resume()

    def chunks(self, chunk_cycles: int = CHUNK_CYCLES,
               progress: Callable[[float], None] | None = None) -> Iterator[SimChunk]:
        """Run the simulation, yielding a ``SimChunk`` every ``chunk_cycles`` output cycles (the last one may be
        shorter and carries the records left); ``progress(fraction)`` is called as it goes. After ``resume`` it
        goes on from the checkpoint's cycle (no settling: that is in the checkpoint)."""
        if self._started:
            raise RuntimeError("a Simulation runs once; start another one")
        if not (isinstance(chunk_cycles, int | np.integer) and chunk_cycles >= 1):
            raise ValueError(f"chunk_cycles = {chunk_cycles!r} must be an integer >= 1")
        self._started = True
        run, spec, cycles, theta_start = self.run, self.model.spec, self.cycles, self.theta_start
        # from theta_start (the settling's start, 2 pi before its first cycle) to the run's end, 0.5 pi past its last
        # boundary: the fraction reaches 1 at the end, not ~1.5 cycles before it as with the 2.5 pi left out
        total_angle = 4.0 * np.pi * (cycles + SETTLE_A_CYCLES + SETTLE_B_CYCLES) + 2.5 * np.pi

        def report() -> None:
            if progress is not None:
                progress(float(np.clip((run.theta_fly - theta_start) / total_angle, 0.0, 1.0)))

        if self._state is None:
            self._state = self._settle(report)
        st, stages = self._state, self.stages

        def advance(stop: float, t_stop: float | None = None) -> bool:
            """``run.advance_to(stop, t_stop=...)``, switching stages at their onset cycles on the way (the kernel
            reads the plant's coefficient array: switched in place)."""
            pending = st.pending
            while pending and 4.0 * np.pi * stages.onsets[pending[0]] <= stop:
                i = pending[0]
                if run.advance_to(4.0 * np.pi * stages.onsets[i], report, t_stop=t_stop):
                    return True
                run.plant.coef[:] = stages.coefficients[i]
                run.set_leak(stages.leaks[i])
                if stages.phases:  # a cylinder's TDC moves (the kernel reads the plant's phase array in place)
                    run.plant.phase[:] = stages.phases[i]
                if stages.sensors:  # the wheel frame moves, a channel's gain or pegging changes
                    run.sc[S_WHEEL_OFF] = stages.sensors[i].wheel_offset_rad
                    t_switch = float(run.state[6][0]) - run.t_out0
                    st.sensors.switch(t_switch, stages.sensors[i])
                    st.changes.append(_sensor_change(stages.onsets[i], t_switch, stages.sensors[i],
                                                     stages.phases[i] if stages.phases else None))
                pending.pop(0)
            return run.advance_to(stop, report, t_stop=t_stop)

        end = 4.0 * np.pi * cycles + 0.5 * np.pi
        while st.done < cycles:
            st.done = min(st.done + chunk_cycles, cycles)
            stop = end if st.done == cycles else 4.0 * np.pi * st.done
            while True:
                # a speed step's hold ends at a cycle boundary (the load changes between two cycles, not inside one)
                target = stop if not st.governed else min(stop, st.governed[0])
                if not advance(target, t_stop=st.steps[0][0] if st.steps else None):
                    if not st.governed or target < st.governed[0]:
                        break
                    run.release_speed()  # a speed step's hold ends at a cycle boundary: the eddy-current law
                    st.governed.pop(0)
                    continue
                t_step, frac, rpm = (*st.steps.pop(0), None)[:3]  # a step time reached: the new point and law
                st.sensors.set_load(np.nan if frac is None else frac)  # a thermal-shock error follows the load
                if frac is None:  # the coast-down: motored cycles against zero load from here on
                    run.coast(*charge_pressures(spec, 0.0))
                    st.step_log.append({"time_s": t_step, "coast_down": True})
                    continue
                omega = run.omega if rpm is None else rpm * np.pi / 30.0
                fuel, tb, _ = self.point(frac, omega)
                run.set_operating(fuel, *charge_pressures(spec, frac))
                if rpm is None:
                    run.change_law(tb + st.correction, st.brake_full + st.correction)
                else:  # held at the new speed, released at the boundary SPEED_HOLD_CYCLES whole cycles on
                    run.hold_speed(omega, tb + st.correction, SPEED_TAU_CYCLES * 4.0 * np.pi / omega)
                    st.governed = [4.0 * np.pi * (np.ceil(run.theta_fly / (4.0 * np.pi)) + SPEED_HOLD_CYCLES)]
                st.step_log.append({"time_s": t_step, "load": frac, "fuel_kg": fuel, "brake_torque_estimate_nm": tb,
                                    **({} if rpm is None else {"rpm": rpm})})
            advance(stop)
            ev = run.drain()
            entries, diag = st.truth.add(ev["cycle_rows"], ev["cycle_index"], ev["grid"])
            records = st.sensors.add(ev["edges"], ev["cam"], ev["samples"], ev["load"],
                                     ev["edges2"] if self.second_wheel else None, ev["grid"])
            if st.done == cycles:
                records += st.sensors.finish()
            diag.update(edge_times_s=ev["edges"][:, 0] - run.t_out0, edge_index=ev["edges"][:, 1].astype(int),
                        pressure_true_pa=ev["samples"])
            if self.second_wheel:
                diag.update(edge2_times_s=ev["edges2"][:, 0] - run.t_out0,
                            edge2_index=ev["edges2"][:, 1].astype(int))
            yield SimChunk(records, entries, diag)
        if progress is not None:
            progress(1.0)
        self.operating.update(load_law=st.law_info, load_steps=st.step_log)
        se = spec.sensors
        wheel = {"first_tooth_deg_stated": se.first_tooth_deg,
                 "first_tooth_deg_true": se.first_tooth_deg - float(np.degrees(self.sensors.wheel_offset_rad)),
                 "tooth_errors_deg": run.tooth_err.tolist(), "cam_deg_stated": self.info.cam_deg,
                 "edge_ticks_first_tooth_index": st.sensors.first_edge_index}
        if st.changes:
            wheel["changes"] = st.changes
        if self.second_wheel:
            w2 = spec.sensors.second_wheel
            wheel["second_wheel"] = {"teeth": w2.teeth, "missing": w2.missing, "first_tooth_deg": w2.first_tooth_deg,
                                     "node": spec.node_names[w2.node], "tooth_errors_deg": run.tooth_err2.tolist()}
        self.truth = st.truth.summary(**self.request, active=[e.to_dict() for e in self.model.effects], wheel=wheel,
                                      operating=self.operating)

    def _settle(self, report: Callable[[], None]) -> _RunState:
        """The unlogged settling (governed, then the final law), tick 0, and the output streams' fresh state."""
        run, theta_start = self.run, self.theta_start
        for i in range(SETTLE_A_CYCLES):
            run.advance_to(theta_start + 2.0 * np.pi + 4.0 * np.pi * (i + 1), report)
            run.govern()
        law_info = run.final_law()
        run.start_output(-2.0 * np.pi, report)
        sensors, truth = self._streams()
        pending = [] if self.stages is None else list(range(1, len(self.stages.onsets)))  # stage switches to come
        correction = law_info["load_torque_settled_nm"] - self.operating["brake_torque_estimate_nm"]
        return _RunState(sensors, truth, pending, [], list(self.steps), [], correction, run.brake_full, law_info, 0)

    def _streams(self) -> tuple[SensorRecords, TruthAccumulator]:
        spec, stages = self.model.spec, self.stages
        # the requested speed scales the load power's noise, the run's first (a speed step does not rescale it)
        sensors = SensorRecords(spec, self.sensors, self.rngs, self.run.t_out0, self.operating["omega_requested_rad_s"],
                                self.second_wheel, self.run.plant.phase, self.request["load"])
        switching = stages is not None and len(stages.onsets) > 1
        truth = TruthAccumulator(spec, self.run.plant, self.cycles, self.run.t_out0,
                                 stages.coefficients_of if switching else None)
        return sensors, truth

    # ---- segments: a run checkpointed between chunks and continued elsewhere --------------------------------------
    def checkpoint(self) -> dict:
        """The run's state after the chunk just yielded (call it between two chunks of ``chunks()``): the plant's,
        the output streams' and the truth's, as plain data (picklable; no model). ``start_simulation`` with the same
        arguments, then ``resume(checkpoint)``, then ``chunks()`` gives the rest of this run: the records and truth
        entries it would have yielded, bit for bit (tests/core/test_simulate_segments.py)."""
        st = self._state
        if st is None:
            raise RuntimeError("a checkpoint is taken between chunks of a running simulation")
        return {"key": self._key(), "plant": self.run.checkpoint(), "sensors": st.sensors.checkpoint(),
                "truth": st.truth.checkpoint(), "run": copy.deepcopy({
                    "pending": st.pending, "changes": st.changes, "steps": st.steps, "step_log": st.step_log,
                    "correction": st.correction, "brake_full": st.brake_full, "law_info": st.law_info,
                    "done": st.done, "governed": st.governed})}

    def resume(self, checkpoint: dict) -> None:
        """Continue this (not yet started) simulation from ``checkpoint`` of a run set up with the same arguments."""
        if self._started or self._state is not None:
            raise RuntimeError("resume a simulation before its chunks() start")
        if checkpoint["key"] != self._key():
            raise ValueError(f"the checkpoint is of another run: {checkpoint['key']} against {self._key()}; start "
                             "the simulation with the same engine, arguments and seed")
        self.run.restore(checkpoint["plant"])
        sensors, truth = self._streams()
        sensors.restore(checkpoint["sensors"])
        truth.restore(checkpoint["truth"])
        r = copy.deepcopy(checkpoint["run"])
        self._state = _RunState(sensors, truth, r["pending"], r["changes"], r["steps"], r["step_log"],
                                r["correction"], r["brake_full"], r["law_info"], r["done"], list(r.get("governed", [])))

    def _key(self) -> dict:
        """What identifies a run's set-up (its checkpoints fit only a run set up the same)."""
        return {"engine": self.model.spec.name, "cycles": self.cycles, **self.request,
                **({"second_wheel": True} if self.second_wheel else {}),
                "effects": [e.to_dict() for e in self.model.effects], "steps": [list(x) for x in self.steps]}


@dataclass
class _RunState:
    """What ``chunks()`` carries from one chunk to the next besides the plant: the output streams, the truth so far,
    the stage switches and load steps still to come (indices, [(time_s, fraction)]), the acquisition's changes and
    the steps taken (for the truth), the load-law correction, the settled full-load brake torque [N m] and law, and
    the output cycles done."""

    sensors: SensorRecords
    truth: TruthAccumulator
    pending: list[int]
    changes: list[dict]
    steps: list
    step_log: list[dict]
    correction: float
    brake_full: float
    law_info: dict
    done: int
    governed: list = field(default_factory=list)  # a speed step's hold ends at this cycle boundary [rad]


def _sensor_change(cycle: int, time_s: float, sensors: SensorSetup, phases: np.ndarray | None) -> dict:
    """The truth's record of the acquisition from output ``cycle`` on (switched at ``time_s`` since tick 0): the
    wheel offset [deg], each channel's gain and pegging [Pa], the true firing angles [deg]."""
    out = {"cycle": int(cycle), "time_s": time_s, "wheel_offset_deg": float(np.degrees(sensors.wheel_offset_rad)),
           "pressure_gain": [float(g) for g in sensors.pressure_gain],
           "pressure_offset_pa": [float(o) for o in sensors.pressure_offset_pa]}
    if phases is not None:
        out["firing_angles_deg"] = [float(a) for a in np.degrees(phases)]
    return out
