"""Speed of the plant simulator: 1 s of genset-v20 at 1500 rpm full load (target < 2 s on one core, compile excluded).

    python -m bench.bench_simulate

Reports the numba compile time separately (a fresh process with an empty numba cache), the wall time of a
13-cycle run (1.04 s logged, plus the unlogged settling), and the marginal cost per simulated second from two run
lengths (settling excluded).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time

CYCLES_PER_S = 1500 / 120.0  # 4-stroke: 12.5 cycles per second at 1500 rpm

_COLD = ("import time; t = time.perf_counter(); from core.model.engine import load_engine; from core.plant.simulate import simulate;"
         " simulate(load_engine('deutz-1cyl'), 2000, 0.5, 1, 0); print(time.perf_counter() - t)")


def _cold_compile_s() -> float:
    """Import + first tiny simulation in a fresh process whose numba cache is empty: the compile cost."""
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache, NUMBA_NUM_THREADS="1")
        out = subprocess.run([sys.executable, "-c", _COLD], capture_output=True, text=True, env=env, check=True)
    return float(out.stdout.strip().splitlines()[-1])


def _timed(spec, cycles: int) -> tuple[float, dict]:
    from frictionwatch.core.plant.simulate import simulate

    t = time.perf_counter()
    r = simulate(spec, 1500.0, 1.0, cycles, 0)
    return time.perf_counter() - t, r.truth


def run() -> dict:
    from frictionwatch.core.model.engine import load_engine
    from frictionwatch.core.plant.simulate import SETTLE_A_CYCLES, SETTLE_B_CYCLES, simulate

    compile_s = _cold_compile_s()
    spec = load_engine("genset-v20")
    simulate(spec, 1500.0, 1.0, 1, 0)  # warm (cache load, first-call dispatch)
    t13, truth = _timed(spec, 13)
    t26, _ = _timed(spec, 26)
    per_s = (t26 - t13) / 13 * CYCLES_PER_S
    return {
        "numba_compile_cold_s": round(compile_s, 2),
        "genset_v20_1s_logged_wall_s": round(t13, 3),
        "settle_cycles_unlogged": SETTLE_A_CYCLES + SETTLE_B_CYCLES,
        "genset_v20_wall_per_simulated_s": round(per_s, 3),
        "target_wall_per_simulated_s": 2.0,
        "real_time_factor": round(1.0 / per_s, 1),
        "fmep_bar": round(truth["fmep_bar"], 4),
    }


if __name__ == "__main__":
    print(json.dumps(run(), indent=1))
