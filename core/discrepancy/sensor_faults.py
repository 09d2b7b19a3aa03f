"""A pressure sensor the monitor flags with a fault no candidate describes: every fit then rests on its lie.

The workflow's fits compare the speed the model makes from the measured pressures with the measured speed. A
pressure channel that lies in a way no candidate holds (a thermal shock: core.monitor.calibration.thermal_shock_watch;
any sensor flag of a kind not listed here) leaves a speed residual that some candidate may fit, on another cylinder
or as another effect: k9k 1800 rpm / 0.6, seed 1, a thermal shock of 0.5 bar on cylinder 2 (design note 156's
effect) was named "tdc_offset cylinder 1, -0.27 +- 0.06 deg" with the monitor's own watch flagging cylinder 2's
sensor in the same log (design note 161). Where the monitor flags such a fault, nothing the speed or the pressure
fits is named: the fits become one side of an ambiguity whose other side is the flagged sensor, the model is left
as it was, and the measurement that tells them apart is said.

The faults a candidate does describe (a TDC offset, a gain, a pegging offset: sensor_health and the running
watches' flags of those kinds) are not this: the candidate is the effect itself, and the workflow names it. Nor is a
trace the pressure-trace check flags (dead, clipped, negated, spiking, mis-phased: core.monitor.checks.pressure_trace):
the monitor stands the siblings' pressure in for it, so no fit rests on its reading.
"""

from __future__ import annotations

from collections.abc import Mapping

from frictionwatch.core.monitor.checks.pressure_trace import TRACE_FLAG_KINDS
from frictionwatch.core.monitor.report.figure_status import split_flag

# the monitor's per-cylinder sensor flags whose fault a candidate of the library describes (tdc_offset,
# pressure_gain, pressure_offset; a trace at or below zero is what a pegging offset low by more than the intake
# pressure reads: maruti 3000 rpm seed 2, pegging -1.5 bar on cylinder 3, flagged nonpositive in 120 of 120 cycles,
# the pegging named right from the pressure): the workflow may name those itself
DESCRIBED = frozenset({"sensor_tdc_offset", "sensor_pressure_gain", "sensor_pressure_offset",
                       "sensor_pressure_nonpositive"})
STOOD_IN = TRACE_FLAG_KINDS  # the trace check's flags: its channel replaced by the siblings' pressure
# a fault counts where its flag stood in at least this many of the log's analysed cycles: the watches' flags are
# window statistics that stay raised once a window shows them (a thermal shock flagged at cycle 99 of 120 stood in
# 21), a one-cycle trace flag is not a sensor's state. A design choice, not tuned on a case
MIN_CYCLES = 5
# the words of each fault kind (split_flag's kind)
KIND_WORDS = {"sensor_thermal_shock": "a thermal shock, a reading low after combustion,",
              "sensor_pressure_dead": "no pressure (a dead channel)", "sensor_pressure_clipped": "a clipped trace",
              "sensor_pressure_negated": "a negated trace", "sensor_pressure_spikes": "spikes in the trace",
              "sensor_pressure_phase": "a trace off its cylinder's phase"}
SEPARATION = "a reference pressure transducer on {where}, or its sensor replaced and the log taken again"


def undescribed_faults(flag_cycles: Mapping[str, int], n_cycles: int) -> list[dict]:
    """The sensor faults of a run no candidate describes: [{"cylinder", "kind", "flag", "cycles", "of"}] for each
    per-cylinder ``sensor_*`` flag outside DESCRIBED and STOOD_IN that stood in at least MIN_CYCLES of the run's
    ``n_cycles`` analysed cycles (``flag_cycles``: flag -> cycles it stood in), by cylinder."""
    return _faults(flag_cycles, n_cycles, lambda kind: kind not in DESCRIBED and kind not in STOOD_IN)


def stood_in_channels(flag_cycles: Mapping[str, int], n_cycles: int) -> list[dict]:
    """The channels the pressure-trace check replaced by their siblings' (STOOD_IN flags, as undescribed_faults):
    nothing in the run reads that cylinder's own pressure, which the verdict says (k9k 1800 rpm seed 23, cylinder
    2's channel dead, negated, clipped or a revolution late: "no significant missing effect", true of the speed,
    silent on the cylinder nothing judged)."""
    return _faults(flag_cycles, n_cycles, lambda kind: kind in STOOD_IN)


def _faults(flag_cycles: Mapping[str, int], n_cycles: int, counted) -> list[dict]:
    out = []
    for flag, count in flag_cycles.items():
        kind, cyl = split_flag(flag)
        if cyl is None or not kind.startswith("sensor_") or not counted(kind) or count < MIN_CYCLES:
            continue
        out.append({"cylinder": cyl, "kind": kind.removeprefix("sensor_"), "flag": flag, "cycles": int(count),
                    "of": int(n_cycles)})
    return sorted(out, key=lambda f: (f["cylinder"], f["kind"]))


def said_fault(f: dict) -> str:
    """'cylinder 2's pressure sensor (flagged: a thermal shock, ..., in 21 of 120 cycles)'."""
    words = KIND_WORDS.get("sensor_" + f["kind"], f["kind"].replace("_", " ") + ",")
    return f"cylinder {f['cylinder']}'s pressure sensor (flagged: {words} in {f['cycles']} of {f['of']} cycles)"


def said_stood_in(channels: list[dict]) -> str:
    """'cylinder 2's pressure channel (flagged: no pressure (a dead channel) in 120 of 120 cycles) was stood in by
    its siblings' pressure: nothing here judges that cylinder's own combustion, compression or sensor'."""
    cyls = sorted({f["cylinder"] for f in channels})
    which = " and ".join(said_fault(f).replace("pressure sensor", "pressure channel") for f in channels)
    verb = "was" if len(channels) == 1 else "were"
    whose = "that cylinder's" if len(cyls) == 1 else "those cylinders'"
    return (f"{which} {verb} stood in by the siblings' pressure: nothing here judges {whose} own combustion, "
            "compression or sensor")


def separation(faults: list[dict]) -> str:
    """The measurement that tells the flagged sensors from what the fits name."""
    cyls = sorted({f["cylinder"] for f in faults})
    where = ("cylinder " if len(cyls) == 1 else "cylinders ") + ", ".join(str(c) for c in cyls)
    return SEPARATION.format(where=where)


__all__ = ["DESCRIBED", "KIND_WORDS", "MIN_CYCLES", "STOOD_IN", "said_fault", "said_stood_in", "separation",
           "stood_in_channels", "undescribed_faults"]
