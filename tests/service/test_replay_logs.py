"""The committed replay logs are what the commands in replay_logs/README.md make, and each one analyses.

"What they make" is compared as numbers, not bytes: the simulator is deterministic for a seed, but BLAS and numba
pick different code on different CPUs, so a fresh run on another machine differs in the last bits (seen: 158 of
44,227 truth floats off by <= 1e-9 relative between OpenBLAS's SkylakeX and Haswell kernels). A tooth tick is the
rounding of a simulated time, so such a difference can move an edge by one tick; a pressure sample by one ADC step.
"""

import json
import shlex
from pathlib import Path

import numpy as np
import pytest
from frictionwatch.core.types import CamBatch, LoadSample, PressureBlock, PressureFrame, ToothBatch
from frictionwatch.drivers.logs.mcap_log import LogReader
from frictionwatch.service.cli import main
from numpy.testing import assert_allclose

from tests.json_close import assert_json_close

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "replay_logs" / "README.md"
TICK_TOLERANCE = 1  # an edge time rounded to the timer on another CPU
PRESSURE_ATOL_PA = 160.0  # one ADC step (the presets: 100 bar over 16 bits = 153 Pa); most samples agree exactly
TRUTH_RTOL = 1e-7  # truth floats: the same simulation, another CPU's rounding


def commands():
    text = README.read_text()
    block = text.split("```sh", 1)[1].split("```", 1)[0]
    return [shlex.split(line) for line in block.splitlines() if line.startswith("frictionwatch ")]


def decoded(path: Path) -> dict:
    """Every stream of a log as arrays: tooth and cam ticks, pressure per cylinder, load samples."""
    log = LogReader(path)
    teeth, cams, load = [], [], []
    pressure: dict[int, list[np.ndarray]] = {}
    pressure_t0: dict[int, list[float]] = {}
    for rec in log.records():
        if isinstance(rec, ToothBatch):
            teeth.append(rec.ticks)
        elif isinstance(rec, CamBatch):
            cams.append(rec.ticks)
        elif isinstance(rec, LoadSample):
            load.append((rec.ticks, rec.torque, rec.power))
        elif isinstance(rec, PressureBlock | PressureFrame):
            rows = [(rec.cylinder, rec.values)] if isinstance(rec, PressureBlock) else zip(rec.cylinders, rec.values)
            for cyl, values in rows:
                pressure.setdefault(cyl, []).append(np.asarray(values))
                pressure_t0.setdefault(cyl, []).append(rec.t0_ticks)
    return {
        "info": log.info, "engine_toml": log.engine_toml, "damage": dict(log.damage),
        "teeth": np.concatenate(teeth), "cams": np.concatenate(cams) if cams else np.zeros(0, np.int64),
        "load": np.array(load, dtype=np.float64).reshape(-1, 3),
        "pressure": {c: np.concatenate(v) for c, v in pressure.items()},
    }


def test_every_committed_log_has_a_command():
    outputs = {Path(c[c.index("-o") + 1]).name for c in commands()}
    committed = {p.name for p in (ROOT / "replay_logs").glob("*.mcap")}
    assert committed == outputs and "demo.mcap" in committed


@pytest.mark.parametrize("argv", commands(), ids=lambda c: Path(c[-1]).stem)
def test_log_is_what_its_command_makes(argv, tmp_path):
    out = Path(argv[argv.index("-o") + 1])
    fresh_path = tmp_path / out.name
    args = argv[1:argv.index("-o")] + ["-o", str(fresh_path)]
    assert main(args) == 0
    fresh, committed = decoded(fresh_path), decoded(ROOT / out)
    assert fresh["info"] == committed["info"] and fresh["engine_toml"] == committed["engine_toml"]
    assert fresh["damage"] == committed["damage"] == {}
    for key in ("teeth", "cams"):
        assert fresh[key].shape == committed[key].shape, key
        assert np.abs(fresh[key] - committed[key]).max(initial=0) <= TICK_TOLERANCE, key
    assert fresh["load"].shape == committed["load"].shape
    assert np.abs(fresh["load"][:, 0] - committed["load"][:, 0]).max(initial=0) <= TICK_TOLERANCE
    assert_allclose(fresh["load"][:, 1:], committed["load"][:, 1:], rtol=1e-6, atol=1e-6)
    assert fresh["pressure"].keys() == committed["pressure"].keys()
    for cyl, values in committed["pressure"].items():
        assert_allclose(fresh["pressure"][cyl], values, rtol=0, atol=PRESSURE_ATOL_PA, equal_nan=True,
                        err_msg=f"cylinder {cyl}")
    truth = out.name.removesuffix(".mcap") + ".truth.json"
    assert_json_close(json.loads((tmp_path / truth).read_text()), json.loads((ROOT / out.parent / truth).read_text()),
                      rtol=TRUTH_RTOL, atol=1e-12, where="truth")
