"""The plant's sensor events -> stream records, chunk by chunk, in arrival order.

``SensorRecords.add(events)`` takes the raw events of one stretch of the run (true tooth-edge and cam times, true
pressure at the sample instants, cumulative load integrals) and returns the records that can already be placed in
arrival order; ``finish()`` returns the rest. Whatever the chunking, the records are the same as for the whole run
converted at once: each noise stream is drawn in order from its own generator (edge jitter, cam jitter, each
cylinder's pressure noise, load noise), a tooth batch or pressure frame is cut from the run's own start (left-over
edges and samples wait for the next chunk), and a record is released only once no later record can arrive before
it (its key below every stream's lower bound for what is still to come).
"""

from __future__ import annotations

import copy

import numpy as np
from frictionwatch.core.model.effects import SensorSetup
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.model.thermal_shock import load_scale, shock_error, shock_shape
from frictionwatch.core.plant.sensors import (
    CAM_DEG,
    PRESSURE_BLOCK_S,
    keyed_records,
    pressure_adc,
    to_ticks,
)
from frictionwatch.core.types import AcquisitionInfo, StreamRecord, WheelInfo


def acquisition_info(spec: EngineSpec, second_wheel: bool = False) -> AcquisitionInfo:
    """What the simulated acquisition states (known before the run starts); ``second_wheel``: the engine file's
    second wheel is logged too."""
    se = spec.sensors
    w = se.second_wheel if second_wheel else None
    return AcquisitionInfo(tick_hz=se.tick_hz, wheel_teeth=se.wheel_teeth, wheel_missing=se.wheel_missing,
                           first_tooth_deg=se.first_tooth_deg, cam_deg=CAM_DEG if se.has_cam else None,
                           pressure_cylinders=tuple(range(1, spec.n_cyl + 1)),
                           second_wheel=None if w is None else WheelInfo(w.teeth, w.missing, w.first_tooth_deg))


class SensorRecords:
    """Sensor models applied to the plant's events of one run, chunk by chunk (see the module docstring).

    rngs: the run's eight generators; 3 edge jitter, 7 cam jitter, 4 pressure noise (one child stream per cylinder),
    5 load noise (a ninth, rngs[8], only with a second wheel: its edge jitter from a child of it). t_out0: the plant
    time [s] of tick 0; omega: the requested speed [rad/s] (load power noise); second_wheel: its edges come in
    ``add``'s ``edges2`` and leave as ``FreeEndToothBatch`` es of one revolution. A thermal-shock error (the
    set-up's ``thermal_shock_pa``) needs each sample's crank angle: from the 1-deg grid ``add`` is given, each
    cylinder's angle from its firing TDC through ``phases`` (z,) rad (the plant's own array, read as it is when a
    chunk comes: a TDC that moves mid-run moves it), its size at the run's ``load`` (``set_load`` at a step)."""

    def __init__(self, spec: EngineSpec, sensors: SensorSetup, rngs: list[np.random.Generator], t_out0: float,
                 omega: float, second_wheel: bool = False, phases: np.ndarray | None = None, load: float = 1.0):
        se = spec.sensors
        w = se.second_wheel if second_wheel else None
        self.per_rev2 = 0 if w is None else w.teeth - w.missing
        self.rng_edge2 = rngs[8].spawn(1)[0] if w is not None else None
        self.edges2 = np.zeros(0, np.int64)  # second-wheel edge ticks not yet in a full batch
        self.spec, self.fx, self.t0, self.omega = spec, sensors, t_out0, omega
        self.rng_edge, self.rng_cam, self.rng_load = rngs[3], rngs[7], rngs[5]
        self.rng_pressure = rngs[4].spawn(spec.n_cyl)
        self.per_rev = se.wheel_teeth - se.wheel_missing
        self.period_ticks = se.tick_hz / se.pressure_rate_hz
        self.block = max(1, round(PRESSURE_BLOCK_S * se.pressure_rate_hz))
        self.edges = np.zeros(0, np.int64)  # edge ticks not yet in a full tooth batch
        self.samples = np.zeros((0, spec.n_cyl))  # readings not yet in a full frame
        self.first_sample = 0  # run index of samples[0]
        self.load_row: np.ndarray | None = None  # the last load row (time, int T dt, int T w dt)
        self.last = {"edge": -1, "cam": -1, "load": 0}  # last tick seen per stream
        self.pending: list[tuple[int, int, StreamRecord]] = []
        self.first_edge_index: int | None = None
        self.switches: list[tuple[float, SensorSetup]] = []  # (time since tick 0 [s], the set-up from then on)
        self.shock_shapes = None
        if sensors.thermal_shock_pa is not None and np.any(sensors.thermal_shock_pa > 0):
            if phases is None:
                raise ValueError("a thermal-shock error needs the cylinders' firing angles (phases)")
            # its time constant in crank angle at the requested speed (a speed step does not rescale it)
            self.shock_shapes = [shock_shape(spec.combustion.start_deg, float(np.degrees(tau * omega)))
                                 for tau in sensors.thermal_shock_tau_s]
        self.phases = phases
        self.shock_scale = (np.zeros(spec.n_cyl) if self.shock_shapes is None
                            else load_scale(load, np.asarray(sensors.thermal_shock_idle)))
        # the last known (time since tick 0 [s], flywheel angle [rad]): tick 0 is at theta_F = -2 pi
        # (core.plant.sim_stream), the grid's rows at 0, 1, 2, ... deg from theta_F = 0
        self.angle_known = np.array([[0.0, -2.0 * np.pi]])
        self.grid_rows = 0
        self.held = np.zeros((0, spec.n_cyl))  # true-pressure samples past the grid's last row (``_placed``)

    _FIELDS = ("edges", "samples", "first_sample", "load_row", "last", "pending", "first_edge_index", "switches",
               "edges2", "shock_scale", "angle_known", "grid_rows", "held")

    def _generators(self) -> list[np.random.Generator]:
        extra = [] if self.rng_edge2 is None else [self.rng_edge2]
        return [self.rng_edge, self.rng_cam, self.rng_load, *self.rng_pressure, *extra]

    def checkpoint(self) -> dict:
        """The streams' state between chunks: partial batches and frames, pending records, the noise generators'
        states (so the continued run draws the same numbers)."""
        out = {name: copy.deepcopy(getattr(self, name)) for name in self._FIELDS}
        out["rng"] = [g.bit_generator.state for g in self._generators()]
        return out

    def restore(self, ck: dict) -> None:
        """Continue from ``checkpoint()`` of the same run (this object made for it, at the same tick 0)."""
        for name in self._FIELDS:
            setattr(self, name, copy.deepcopy(ck[name]))
        for g, state in zip(self._generators(), ck["rng"], strict=True):
            g.bit_generator.state = state

    def switch(self, time_s: float, sensors: SensorSetup) -> None:
        """From ``time_s`` [s since tick 0] on, the pressure readings take ``sensors``' gains and pegging (a sensor
        fault with an onset, core.plant.sim_stream); the noise streams go on as before. Call it before the samples
        of that time are added."""
        self.switches.append((float(time_s), sensors))

    def set_load(self, load: float) -> None:
        """From the samples added next on, the thermal-shock error is sized at ``load`` (0..1; NaN: motored)."""
        if self.shock_shapes is not None:
            self.shock_scale = load_scale(load, np.asarray(self.fx.thermal_shock_idle))

    def add(self, edges: np.ndarray, cam: np.ndarray, samples: np.ndarray, load: np.ndarray,
            edges2: np.ndarray | None = None, grid: np.ndarray | None = None) -> list[StreamRecord]:
        """Records releasable after these events: edges (n, 2) = (time s, tooth index), cam (c,) times [s],
        samples (m, z) true pressure [Pa] at the next m sample instants, load (l, 3) cumulative load rows, edges2
        (n2, 2) the second wheel's edges (with one), grid (g, k) the 1-deg grid's rows continuing from theta_F = 0
        (column 0 their plant time [s]; needed with a thermal-shock error)."""
        self._track_angle(grid)
        self._convert(edges, cam, samples, load, final=False, edges2=edges2)
        # the least key any record still to come can have: tooth and cam ticks strictly increase, a frame not yet
        # cut ends at or after the next sample, a load sample may round to the tick of the last one
        bound = min(self.last["edge"] + 1, self._cam_bound(),
                    round((self.first_sample + len(self.samples)) * self.period_ticks), self.last["load"])
        if self.per_rev2:
            bound = min(bound, self.last.get("edge2", -1) + 1)
        ready = [r for r in self.pending if r[0] < bound]
        self.pending = [r for r in self.pending if r[0] >= bound]
        return [r[2] for r in ready]

    def finish(self) -> list[StreamRecord]:
        """The remaining records (the last tooth batch and pressure frame may be short)."""
        self._convert(np.zeros((0, 2)), np.zeros(0), np.zeros((0, self.spec.n_cyl)), np.zeros((0, 3)), final=True)
        out, self.pending = [r[2] for r in self.pending], []
        return out

    def _track_angle(self, grid: np.ndarray | None) -> None:
        """Keep the grid's rows of this stretch (with the last one before it) as (time since tick 0, theta_F)."""
        if self.shock_shapes is None or grid is None or not len(grid):
            return
        g = len(grid)
        theta = (self.grid_rows + np.arange(g)) * (np.pi / 180.0)
        self.grid_rows += g
        rows = np.column_stack([grid[:, 0] - self.t0, theta])
        self.angle_known = np.concatenate([self.angle_known[-1:], rows])

    def _placed(self, samples: np.ndarray, final: bool) -> np.ndarray:
        """The true-pressure samples (those held back first) whose angle the grid has placed; the later ones (the
        last degree of a stretch) are held back for the next stretch's grid, so that every sample's angle is
        interpolated as in a run converted in one piece (``final``: all, the last ones on at the last row's rate)."""
        held = np.concatenate([self.held, samples]) if len(self.held) else samples
        if final:
            self.held = held[:0]
            return held
        t = (self.first_sample + len(self.samples) + np.arange(len(held))) / self.spec.sensors.pressure_rate_hz
        n = int(np.searchsorted(t, self.angle_known[-1, 0], side="right"))
        self.held = held[n:]
        return held[:n]

    def _shock(self, m: int) -> np.ndarray:
        """(m, z) the thermal-shock error [Pa] of the next m samples: each sample's flywheel angle interpolated on the
        grid (linear; beyond its last row only at the run's end, on at the last row's rate), minus each cylinder's
        firing angle. In the log's first revolution, before the grid's first row at theta_F = 0, the angle is
        interpolated from tick 0 over the whole revolution (up to ~1 deg off: k9k 2000 rpm)."""
        known = self.angle_known
        t = (self.first_sample + len(self.samples) + np.arange(m)) / self.spec.sensors.pressure_rate_hz
        theta = np.interp(t, known[:, 0], known[:, 1])
        if len(known) >= 2:
            rate = (known[-1, 1] - known[-2, 1]) / (known[-1, 0] - known[-2, 0])
            after = t > known[-1, 0]
            theta[after] = known[-1, 1] + rate * (t[after] - known[-1, 0])
        local = theta[:, None] - np.asarray(self.phases)[None, :]
        return shock_error(local, self.shock_shapes, self.shock_scale * np.asarray(self.fx.thermal_shock_pa))

    def _cam_bound(self) -> float:
        return self.last["cam"] + 1 if self.spec.sensors.has_cam else np.inf

    def _channel_errors(self, m: int) -> tuple[np.ndarray, np.ndarray]:
        """(gain, offset [Pa]), each (m, z), of the next m samples (sample i of the run at i / rate s since tick 0):
        the run's set-up, then each switch from its time on."""
        fx, z = self.fx, self.spec.n_cyl
        gain = np.broadcast_to(np.asarray(fx.pressure_gain, dtype=np.float64), (m, z)).copy()
        offset = np.broadcast_to(np.asarray(fx.pressure_offset_pa, dtype=np.float64), (m, z)).copy()
        if self.switches and m:
            t = (self.first_sample + len(self.samples) + np.arange(m)) / self.spec.sensors.pressure_rate_hz
            for t_switch, setup in self.switches:
                after = t >= t_switch
                gain[after] = setup.pressure_gain
                offset[after] = setup.pressure_offset_pa
        return gain, offset

    def _convert(self, edges, cam, samples, load, *, final: bool, edges2=None) -> None:
        se, fx, t0 = self.spec.sensors, self.fx, self.t0
        jitter = fx.edge_jitter_ns * 1e-9
        if self.first_edge_index is None and edges.size:
            self.first_edge_index = int(edges[0, 1])
        ticks = to_ticks(edges[:, 0] - t0, se.tick_hz, jitter, self.rng_edge, after=self.last["edge"])
        cam_ticks = (to_ticks(cam - t0, se.tick_hz, jitter, self.rng_cam, after=self.last["cam"]) if se.has_cam
                     else np.zeros(0, np.int64))
        if ticks.size:
            self.last["edge"] = int(ticks[-1])
        if cam_ticks.size:
            self.last["cam"] = int(cam_ticks[-1])
        all_edges = np.concatenate([self.edges, ticks])
        n_edges = all_edges.size if final else all_edges.size - all_edges.size % self.per_rev
        self.edges = all_edges[n_edges:]

        if self.shock_shapes is not None:
            samples = self._placed(samples, final)
        gain, offset = self._channel_errors(len(samples))
        if self.shock_shapes is not None and len(samples):
            samples = samples + self._shock(len(samples))
        readings = pressure_adc(samples, se, se.pressure_noise_pa * fx.pressure_noise_scale, self.rng_pressure,
                                offset, gain)
        all_samples = np.concatenate([self.samples, readings])
        n_samples = len(all_samples) if final else len(all_samples) - len(all_samples) % self.block
        first_sample = self.first_sample
        self.samples, self.first_sample = all_samples[n_samples:], first_sample + n_samples

        rows = load if self.load_row is None else np.concatenate([self.load_row[None, :], load])
        torque = power = load_ticks = np.zeros(0)
        if len(rows):
            self.load_row = rows[-1].copy()
            dt = np.diff(rows[:, 0])
            torque, power = np.diff(rows[:, 1]) / dt, np.diff(rows[:, 2]) / dt
            sig = fx.load_noise_frac * self.spec.rated_torque_nm
            if sig > 0 and torque.size:
                e = self.rng_load.normal(0.0, sig, torque.size)
                torque, power = torque + e, power + e * self.omega
            load_ticks = np.round((rows[1:, 0] - t0) * se.tick_hz).astype(np.int64)
            if load_ticks.size:
                self.last["load"] = int(load_ticks[-1])
        ready2 = None
        if self.per_rev2:  # the second wheel: its own jitter stream, batches of one revolution of its wheel
            e2 = np.zeros((0, 2)) if edges2 is None else edges2
            ticks2 = to_ticks(e2[:, 0] - t0, se.tick_hz, jitter, self.rng_edge2, after=self.last.get("edge2", -1))
            if ticks2.size:
                self.last["edge2"] = int(ticks2[-1])
            all2 = np.concatenate([self.edges2, ticks2])
            n2 = all2.size if final else all2.size - all2.size % self.per_rev2
            ready2, self.edges2 = all2[:n2], all2[n2:]
        self.pending += keyed_records(all_edges[:n_edges], self.per_rev, cam_ticks, all_samples[:n_samples],
                                      self.period_ticks, self.block, load_ticks, torque, power, first_sample,
                                      ready2, max(self.per_rev2, 1))
        self.pending.sort(key=lambda r: r[:2])  # stable: records of one stream and key keep their order
