"""Driver of the plant kernel: holds its arrays, runs it chunk by chunk, switches load laws, hands over its events.

Load law during settling ("phase A"): a stiff speed-holding version of the preset's law (dyno: slope 2 J/T_cycle;
grid: near-critical damping of the electromechanical mode) with deterministic combustion, so the plant reaches its
mean equilibrium within a few cycles. The final law then carries exactly the measured equilibrium torque at the
settled speed: dyno T_L = c + k omega^s with k = max(T_b, 0.25 T_b,full)/omega^s (c = 0 at loads >= 25 %,
Seddak's c = 0, s = 1 case); grid T_L0 = T_b and delta_0 = mean rotor angle. Logs start after this.
"""

from __future__ import annotations

import numpy as np
from frictionwatch.core.model.effects import SensorSetup
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.model.thermo import CylinderModel
from frictionwatch.core.plant.plant import (
    FOUR_PI,
    I_N_CAM,
    I_N_CYC,
    I_N_EDGE,
    I_N_EDGE2,
    I_N_GRID,
    I_N_LOAD,
    I_N_SAMPLE,
    I_NEXT_CAM,
    I_NEXT_CYCLE,
    I_NEXT_EDGE,
    I_NEXT_EDGE2,
    I_NIST,
    N_FQ,
    NQ_GLOBAL,
    OP_BETA,
    OP_FUEL,
    OP_N,
    OP_OMEGA,
    OP_PEXH,
    OP_PINT,
    OP_PIVC,
    OP_SOC,
    S_CAM,
    S_CMIN,
    S_GRID_FRICTION,
    S_H,
    S_LPERIOD,
    S_NODE2,
    S_OUT_AT,
    S_PPERIOD,
    S_QPERKG,
    S_T0OUT,
    S_WHEEL_OFF,
    TWO_PI,
    Firing,
    PlantArrays,
    PressureTraces,
)
from frictionwatch.core.plant.plant_advance import advance
from frictionwatch.core.plant.plant_setup import PlantModel, scalars
from frictionwatch.core.plant.sensors import (
    CAM_DEG,
    LOAD_RATE_HZ,
    edge_angles,
    first_index_at_or_after,
    second_wheel_sensors,
    tooth_errors,
)

FAR = 1 << 50  # event index that never fires
# flywheel cycles one call of the kernel may integrate (its output buffers hold that and half a cycle more): each call
# pays numba's dispatch, which types the model's tuple of first-class kernels (1-2.5 ms a call on genset-v20 at load
# ~8); a call per cycle paid it every cycle (design note 129). Not a whole chunk (8): the progress is reported after
# each call, and a run's last 10 % should show (a Ctrl-C there: tests/service/test_cli_files.py). The events do not
# depend on where the calls end: a call that fills a buffer returns and the next goes on (status 2)
CALL_CYCLES = 4
# the flywheel below this speed has stopped for every measurement here (a starter cranks at ~100-200 rpm): a run
# asked for more cycles than a coast-down leaves before the engine stops ends with a one-line error, not a plant
# integrating a standstill for ever (simulate k9k 2000 rpm, 60 cycles, coast_down at 1.2 s: design note 166)
STOPPED_RAD_S = 30.0 * np.pi / 30.0


class PlantRun:
    def __init__(self, spec: EngineSpec, plant: PlantModel, tmodel: CylinderModel, *, h: float, omega: float,
                 sensors: SensorSetup, rngs: list[np.random.Generator], second_wheel: bool = False):
        """second_wheel: also the edges of the engine file's second wheel (``spec.sensors.second_wheel``), its tooth
        errors drawn from ``rngs[8]`` (the run's ninth generator, made only then: every other stream unchanged). The
        total friction on the 1-deg grid is evaluated (``scalars``' default) until ``record_friction_grid(False)``."""
        self.spec, self.plant, self.sensors, self.rngs, self.omega = spec, plant, sensors, rngs, omega
        z, n = spec.n_cyl, plant.n
        sc = scalars(spec, plant)
        sc[S_H] = h
        sc[S_WHEEL_OFF] = sensors.wheel_offset_rad
        sc[S_CAM] = np.radians(CAM_DEG)
        sc[S_PPERIOD] = 1.0 / spec.sensors.pressure_rate_hz
        sc[S_T0OUT] = np.inf
        sc[S_OUT_AT] = np.inf  # no output start armed (``start_output``)
        sc[S_LPERIOD] = 1.0 / LOAD_RATE_HZ
        sc[S_QPERKG] = spec.combustion.combustion_efficiency * spec.combustion.lhv_j_per_kg
        self.sc = sc
        self.lp = np.zeros(12)
        self.op = np.zeros(OP_N)
        self.tmodel = tmodel
        traces = PressureTraces(np.zeros((z, 3, tmodel.theta.shape[0])), np.full((z, 3), -FAR, dtype=np.int64),
                                tmodel.step)
        # the kernel's model: its arrays (sc, lp, traces) are updated in place from here on
        self.model = PlantArrays((plant.inertia, plant.stiff, plant.damp, np.zeros(n), np.zeros(n), np.zeros(n)),
                                 plant.cylinders, sc, spec.friction_params(), self.lp, traces)
        self.tooth_err = tooth_errors(spec.sensors, rngs[2], sensors.tooth_sigma_deg, sensors.runout_deg,
                                      sensors.runout_phase_deg)
        self.wheel2 = second_wheel_sensors(spec) if second_wheel else None
        self.tooth_err2 = np.zeros(0)
        edges2 = (np.zeros(0), np.zeros(0))
        if self.wheel2 is not None:
            # its own wheel: random errors of the same rms, its own runout phase (another wheel, mounted apart)
            g = rngs[8]
            self.tooth_err2 = tooth_errors(self.wheel2, g, sensors.tooth_sigma_deg, sensors.runout_deg,
                                           float(g.uniform(0.0, 360.0)))
            edges2 = (edge_angles(self.wheel2, self.tooth_err2),
                      np.arange(self.wheel2.wheel_teeth - self.wheel2.wheel_missing, dtype=np.float64))
            # rigid plant: one node carries everything; flexible: the wheel's own node
            sc[S_NODE2] = spec.sensors.second_wheel.node if plant.n == len(spec.node_names) else 0
        self.edges = (edge_angles(spec.sensors, self.tooth_err),
                      np.arange(spec.sensors.wheel_teeth - spec.sensors.wheel_missing, dtype=np.float64), *edges2)
        nq = z * plant.nq_cyl + NQ_GLOBAL
        # (th, om, acc, cumulative integrals, powers, pmax, [t, last cycle time], the cylinders' node quantities at
        # the last two steps, the powers at the step before: core.plant.plant_advance)
        self.state = (np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(nq), np.zeros(nq), np.zeros(z),
                      np.array([0.0, -1.0]), np.zeros((2, N_FQ, n)), np.zeros(nq))
        self.ist = np.zeros(I_NIST, dtype=np.int64)
        for i in (I_NEXT_EDGE, I_NEXT_CAM, I_NEXT_EDGE2):
            self.ist[i] = FAR
        self.outs: tuple = ()
        self._size_outputs(omega)
        self.collected: list[list[np.ndarray]] = [[] for _ in self.outs]
        # the last two cycle-boundary rows handed over by ``drain`` (NaN before any): a speed step's release reads the
        # cycle before it (``_cycle_means``) also where that cycle's rows were drained already
        self.tail = np.full((2, self.outs[0].shape[1]), np.nan)
        self.cycle_n0 = 0
        self.rows_drained = 0
        self.t_out0 = np.nan
        self.law: dict = {}
        self.leak = np.zeros(z)

    def _size_outputs(self, omega: float) -> None:
        """The kernel's output buffers, one call's worth (``CALL_CYCLES`` cycles and a half at ``omega``): made again
        for a lower speed (a speed step), where a cycle holds more samples."""
        spec, z = self.spec, self.spec.n_cyl
        revs = 2 * CALL_CYCLES + 1  # revolutions a call may span (a call that fills a buffer returns early anyway)
        t_call = revs * TWO_PI / omega
        n_edge = revs * spec.sensors.wheel_teeth + 16
        n_edge2 = revs * self.wheel2.wheel_teeth + 16 if self.wheel2 is not None else 1
        n_samp = int(t_call * spec.sensors.pressure_rate_hz) + 32
        width = 1 + z * self.plant.nq_cyl + NQ_GLOBAL + z
        self.outs = (np.zeros((CALL_CYCLES + 3, width)), np.zeros((360 * revs + 40, 3)), np.zeros((n_edge, 2)),
                     np.zeros(CALL_CYCLES + 3), np.zeros((n_samp, z)), np.zeros((int(t_call * LOAD_RATE_HZ) + 4, 3)),
                     np.zeros((n_edge2, 2)))
        self.outs_omega = float(omega)

    # ---- setup ----------------------------------------------------------------------------------------------
    def set_state(self, theta: np.ndarray, omega: float) -> None:
        th, om = self.state[0], self.state[1]
        th[:] = theta
        om[:] = omega
        self.cycle_n0 = int(np.ceil(th[self.plant.fly] / FOUR_PI))
        self.ist[I_NEXT_CYCLE] = self.cycle_n0

    def set_operating(self, fuel_kg: float, p_ivc: float, p_int: float, p_exh: float) -> None:
        cb = self.spec.combustion
        op = self.op
        op[OP_FUEL], op[OP_SOC], op[OP_BETA] = fuel_kg, np.radians(cb.start_deg), cb.premixed_fraction
        op[OP_PIVC], op[OP_PINT], op[OP_PEXH] = p_ivc, p_int, p_exh
        if op[OP_OMEGA] == 0.0:
            op[OP_OMEGA] = self.omega

    def set_perturbations(self, spread, misfire, sig_q, sig_soc_deg, sig_beta, theta_start, theta_switch,
                          cycles, misfire_from=None) -> None:
        """Per cylinder-cycle (fuel factor, SOC shift rad, premixed factor); cycle c of cylinder k fires at
        theta_F = 4 pi c + phase_k. Cycles firing before ``theta_switch`` get the deterministic mean. Cylinder k
        misfires only from its output cycle ``misfire_from[k]`` on (default: from the start)."""
        z, phase = self.spec.n_cyl, self.plant.phase
        cmin = int(np.floor((theta_start - phase.max() - 1.0 + TWO_PI) / FOUR_PI)) - 1
        ncc = cycles + 4 - cmin
        self.sc[S_CMIN] = cmin
        g = self.rngs[0]
        eq, es, eb = g.standard_normal((3, z, ncc))
        start = np.full(z, -FAR) if misfire_from is None else np.asarray(misfire_from)
        misfire = np.where(cmin + np.arange(ncc)[None, :] >= start[:, None], np.asarray(misfire)[:, None], 0.0)
        fired = self.rngs[6].random((z, ncc)) >= misfire
        pert = np.empty((z, ncc, 3))
        pert[..., 0] = spread[:, None] * np.maximum(1.0 + sig_q * eq, 0.0) * fired
        pert[..., 1] = np.radians(sig_soc_deg) * es
        pert[..., 2] = np.maximum(1.0 + sig_beta * eb, 0.0)
        fire_at = FOUR_PI * (cmin + np.arange(ncc))[None, :] + phase[:, None]
        mean = fire_at <= theta_switch
        pert[..., 0] = np.where(mean, spread[:, None] * (1.0 - misfire), pert[..., 0])
        pert[..., 1] = np.where(mean, 0.0, pert[..., 1])
        pert[..., 2] = np.where(mean, 1.0, pert[..., 2])
        self.pert = np.ascontiguousarray(pert)

    def record_friction_grid(self, on: bool) -> None:
        """Evaluate the total friction on the 1-deg grid (else NaN there; nothing else changes)."""
        self.sc[S_GRID_FRICTION] = 1.0 if on else 0.0

    def set_leak(self, leak: np.ndarray) -> None:
        self.leak = np.ascontiguousarray(leak, dtype=np.float64)

    def set_ripple(self, amplitude: float, order: float, phase: float) -> None:
        self.lp[9:12] = amplitude, order, phase

    # ---- load laws --------------------------------------------------------------------------------------------
    def settle_law(self, brake: float, brake_full: float, min_frac: float) -> None:
        """Dyno: the preset's law c + k omega^s (k from the estimate, re-tuned each settle cycle by ``govern``);
        grid: near-critical damping of the electromechanical mode while settling."""
        spec, lp = self.spec, self.lp
        self.min_frac, self.brake_full = min_frac, brake_full
        j_tot = float(self.plant.mean_inertia.sum())
        if spec.load.kind == "grid":
            ke, de = spec.load.grid_stiffness_nm_per_rad, spec.load.grid_damping_nms_per_rad
            lp[0:9] = [1.0, 0.0, 0.0, 1.0, brake, ke, max(de, 2.0 * np.sqrt(ke * j_tot)),
                       self.state[0][self.plant.load], self.omega]
        else:
            self._dyno(brake, self.omega)

    def _dyno(self, brake: float, w: float) -> None:
        """T_L = c + k omega^s carrying ``brake`` at speed w: c = 0 unless brake < min_frac * full-load brake."""
        s = self.spec.load.exponent
        k = max(brake, self.min_frac * self.brake_full, 1e-6) / w**s
        self.lp[0:9] = [0.0, brake - k * w**s, k, s, 0.0, 0.0, 0.0, 0.0, w]

    def _cycle_means(self, cycles: int = 1) -> tuple[float, float, float, float]:
        """Over the last ``cycles`` complete cycles: (engine net torque = (W_g - W_f - W_damp)/angle, mean speed,
        time-mean load torque, time-mean theta_L - Omega_g t)."""
        rows = np.concatenate([self.tail, *self.collected[0]])[-cycles - 1:]
        z = self.spec.n_cyl
        d = rows[-1] - rows[0]
        cum = d[1:]
        q, n_terms = self.plant.nq_cyl, self.plant.coef.shape[1]
        w_g = sum(cum[k * q] for k in range(z))
        w_f = sum(float(self.plant.coef[k] @ cum[k * q + 1:k * q + 1 + n_terms]) + cum[k * q + 1 + n_terms]
                  for k in range(z))
        g = z * q
        ang = cycles * FOUR_PI
        return (w_g - w_f - cum[g + 1]) / ang, ang / d[0], cum[g + 2] / d[0], cum[g + 3] / d[0]

    def govern(self) -> None:
        """Settle-cycle speed governor (dyno only): re-tune the law so the engine holds the requested speed."""
        if self.spec.load.kind == "grid":
            return
        t_net, w_mean, _, _ = self._cycle_means()
        j_tot = float(self.plant.mean_inertia.sum())
        self._dyno(t_net + 0.7 * j_tot / (FOUR_PI / self.omega) * (w_mean - self.omega), self.omega)

    def final_law(self) -> dict:
        """Freeze the law for the logged part; grid: T_L0 and delta_0 from the last two settle cycles."""
        t_net, w_mean, t_load, delta = self._cycle_means(2)
        self.law = {"kind": self.spec.load.kind, "engine_net_torque_nm": float(t_net),
                    "load_torque_settled_nm": float(t_load), "omega_settled_rad_s": float(w_mean)}
        if self.spec.load.kind == "grid":
            self.lp[0:9] = [1.0, 0.0, 0.0, 1.0, t_load, self.spec.load.grid_stiffness_nm_per_rad,
                            self.spec.load.grid_damping_nms_per_rad, delta, self.omega]
            self.law.update(t_l0_nm=float(t_load), delta0_rad=float(delta), grid_omega_rad_s=float(self.omega),
                            k_e=float(self.lp[5]), d_e=float(self.lp[6]))
        self._describe()
        return self.law

    def _describe(self) -> None:
        if self.spec.load.kind != "grid":
            self.law.update(c_nm=float(self.lp[1]), k=float(self.lp[2]), s=float(self.lp[3]))

    def change_law(self, brake: float, brake_full: float) -> None:
        """Load step: the law that carries ``brake`` [N m] at the requested speed."""
        self.brake_full = brake_full
        if self.spec.load.kind == "grid":
            self.lp[4] = brake
        else:
            self._dyno(brake, self.omega)

    def hold_speed(self, omega: float, brake: float, tau_s: float) -> None:
        """Speed step (dyno only): from here on ``omega`` [rad/s] is the requested speed, and until
        ``release_speed`` the dyno holds it as a speed-controlled one does, T = brake + (J / tau)(w - omega): the
        engine reaches the new speed within a few ``tau_s`` instead of the eddy-current law's J / k (~20 cycles).
        Re-tuning the eddy-current law at each cycle boundary instead (``govern``, as while settling) was tried: it
        overshot a 1200 rpm step by 280 rpm and left a 7 % drift."""
        if self.spec.load.kind == "grid":
            raise ValueError(f"{self.spec.name}'s load is the grid: its speed is the grid's, a speed step is not "
                             "possible")
        self.omega = float(omega)
        if self.omega < self.outs_omega:
            self._size_outputs(self.omega)
        k = float(self.plant.mean_inertia.sum()) / tau_s
        self.lp[0:9] = [0.0, brake - k * self.omega, k, 1.0, 0.0, 0.0, 0.0, 0.0, self.omega]

    def release_speed(self) -> None:
        """After a speed step: the eddy-current law again, carrying at the new speed the engine's net torque over the
        last held cycle (its speed within e^-hold of the step's; the engine's torque hardly changes with speed): the
        engine stays there. Not the held dyno's mean load, which carries the damping the stiff law puts on the shaft
        line's ripple (k9k at 1800 rpm: 3 N m more than the engine's, a 3 % drift after the release); not ``govern``'s
        correction for the speed error either, which is made to be iterated."""
        t_net, _, _, _ = self._cycle_means()
        self._dyno(t_net, self.omega)

    def coast(self, p_ivc: float, p_int: float, p_exh: float) -> None:
        """Ignition off and the load disconnected: motored cycles (no fuel) against zero load torque and no load
        ripple, whatever the preset's law: a coast-down."""
        self.set_operating(0.0, p_ivc, p_int, p_exh)
        self.lp[:] = 0.0
        self.lp[3] = 1.0
        self.law.update(coast_down=True)

    # ---- checkpoints (core.plant.sim_stream: a run continued in another process) ----------------------------------
    _ARRAYS = ("ist", "sc", "lp", "op", "tail")
    _SCALARS = ("t_out0", "cycle_n0", "rows_drained", "brake_full", "min_frac", "omega")

    def checkpoint(self) -> dict:
        """Everything of the plant that changes as it runs (state, counters, law, operating point, the pressure
        traces in hand, switched coefficients, phases and leaks), as copies; between chunks only (nothing collected
        and not drained). The rest is made again, identically, by ``start_simulation`` from the same arguments."""
        if any(self.collected):
            raise RuntimeError("a plant checkpoint is taken between chunks (events not yet drained)")
        out = {name: getattr(self, name).copy() for name in self._ARRAYS}
        out.update({name: getattr(self, name) for name in self._SCALARS})
        traces = self.model.traces
        out.update(state=[a.copy() for a in self.state], pressure=traces.pressure.copy(), cycle=traces.cycle.copy(),
                   leak=self.leak.copy(), coef=self.plant.coef.copy(), phase=self.plant.phase.copy(), law=dict(self.law))
        return out

    def restore(self, ck: dict) -> None:
        """Continue from ``checkpoint()`` of the same run: the kernel's arrays are overwritten in place (its records
        hold them), the rest replaced."""
        for name in self._ARRAYS:
            getattr(self, name)[:] = ck[name]
        for name in self._SCALARS:
            setattr(self, name, ck[name])
        if self.omega < self.outs_omega:  # a speed step before the checkpoint
            self._size_outputs(self.omega)
        for a, b in zip(self.state, ck["state"]):
            a[:] = b
        self.model.traces.pressure[:] = ck["pressure"]
        self.model.traces.cycle[:] = ck["cycle"]
        self.plant.coef[:] = ck["coef"]
        self.plant.phase[:] = ck["phase"]
        self.leak = ck["leak"].copy()
        self.law = dict(ck["law"])

    # ---- running ----------------------------------------------------------------------------------------------
    @property
    def theta_fly(self) -> float:
        return float(self.state[0][self.plant.fly])

    def advance_to(self, theta_stop: float, report, t_stop: float | None = None) -> bool:
        """Integrate to flywheel angle ``theta_stop``; stop early at output time ``t_stop`` [s] (returns True then)."""
        t_abs = np.inf if t_stop is None else self.t_out0 + t_stop
        while True:
            chunk = min(theta_stop, self.theta_fly + CALL_CYCLES * FOUR_PI)
            status = advance(self.model, self._firing(), self.edges, self.state, self.ist, self.outs, chunk, t_abs)
            self._flush()
            if status == 3:
                raise RuntimeError("plant: a cylinder pressure trace was missing (internal error)")
            if status == 4:
                raise RuntimeError("plant: the state is no longer finite (integration diverged)")
            report()
            if status == 1:
                return True
            if status == 0 and self.theta_fly >= theta_stop:
                return False
            if float(self.state[1][self.plant.fly]) < STOPPED_RAD_S:
                raise ValueError(f"the engine stopped (below {STOPPED_RAD_S * 30.0 / np.pi:.0f} rpm) "
                                 f"{float(self.state[6][0]) - self.t_out0:.2f} s into the output, before the cycles "
                                 "asked for: ask fewer cycles, or a later coast_down time_s")

    def _firing(self) -> Firing:
        """The kernel's Firing record of the current operating point, perturbations and leak areas."""
        tm = self.tmodel
        return Firing(self.op, self.pert, self.leak, tm.constants, tm.vol_half, tm.dvol_half)

    def _flush(self) -> None:
        counts = (I_N_CYC, I_N_GRID, I_N_EDGE, I_N_CAM, I_N_SAMPLE, I_N_LOAD, I_N_EDGE2)
        for buf, store, ci in zip(self.outs, self.collected, counts):
            m = int(self.ist[ci])
            if m:
                store.append(buf[:m].copy())
            self.ist[ci] = 0

    def start_output(self, theta_out: float, report) -> None:
        """Integrate on to flywheel angle ``theta_out``, ahead, with tick 0 at its exact crossing: the kernel places
        it inside its step on the step's Hermite, as it places the tooth edges (``step_events``), and starts the
        pressure and load samples there; tooth and cam edges are recorded from that time on. (Tick 0 at the first
        step past it moved every record's time by up to a step when the step changed: design note 123.)"""
        if self.theta_fly >= theta_out:
            raise RuntimeError("the output's start is armed before the flywheel reaches it")
        self.sc[S_OUT_AT] = theta_out
        # edges from the angles now: the kernel passes over those before tick 0 without recording them
        theta_w = self.theta_fly + self.sc[S_WHEEL_OFF]
        self.ist[I_NEXT_EDGE] = first_index_at_or_after(theta_w, self.edges[0], TWO_PI)
        if self.spec.sensors.has_cam:
            self.ist[I_NEXT_CAM] = int(np.ceil((theta_w - self.sc[S_CAM]) / FOUR_PI))
        if self.wheel2 is not None:
            theta2 = float(self.state[0][int(self.sc[S_NODE2])])
            self.ist[I_NEXT_EDGE2] = first_index_at_or_after(theta2, self.edges[2], TWO_PI)
        self.advance_to(theta_out, report)
        self.t_out0 = float(self.sc[S_T0OUT])
        if not np.isfinite(self.t_out0):
            raise RuntimeError("plant: the output's start was not reached (internal error)")

    def drain(self) -> dict:
        """The events recorded since the last drain, handed over and forgotten here (so a long run holds one stretch
        at a time): cycle-boundary rows with their boundary index (negative while settling), the 1-deg grid from
        theta_F = 0, tooth edges (time, index), cam edge times, true pressure at the sample instants, load rows.
        Drain only once the settling is over (``govern`` and ``final_law`` read the rows collected until then)."""
        def cat(i: int, width: int) -> np.ndarray:
            return np.concatenate(self.collected[i]) if self.collected[i] else np.zeros((0, width))

        rows = cat(0, self.outs[0].shape[1])
        out = {"cycle_rows": rows, "cycle_index": self.cycle_n0 + self.rows_drained + np.arange(rows.shape[0]),
               "grid": cat(1, 3), "edges": cat(2, 2), "cam": np.concatenate(self.collected[3] or [np.zeros(0)]),
               "samples": cat(4, self.spec.n_cyl), "load": cat(5, 3), "edges2": cat(6, 2)}
        self.rows_drained += rows.shape[0]
        self.tail = np.concatenate([self.tail, rows])[-2:].copy()
        for store in self.collected:
            store.clear()
        return out
