"""Rows in the service contract's shapes for the store tests.

The numbers are made up but shaped like a genset's (None where a figure has no value, as the contract says).
"""

from __future__ import annotations

import numpy as np

TOML = '[engine]\nname = "test-4cyl"\n'
STATUSES = ("measured", "share", "prior", "unresolved", "withheld")


def summary(i: int, z: int = 4, engine_id: str = "eng-1") -> dict:
    rng = np.random.default_rng(i)
    return {"engine_id": engine_id, "cycle_index": i, "t_start_s": 0.08 * i, "rpm_mean": 1500.0 + rng.normal(),
            "load_torque_nm": 5000.0 + 10 * rng.normal(), "load_power_kw": 785.4 + rng.normal(),
            "imep_bar": list(18.0 + rng.normal(size=z)), "pmax_bar": list(150.0 + rng.normal(size=z)),
            "friction_balance_nm": None if i % 5 == 0 else 300.0 + rng.normal(),
            "flags": ["no_previous_cycle"] if i == 0 else []}


def losses(i: int, z: int = 4, status: str = "measured") -> list[dict]:
    rng = np.random.default_rng(10_000 + i)
    out = []
    for k in range(1, z + 1):
        valued = status in ("measured", "share", "prior")
        out.append({"cylinder": k, "fmep_bar": float(rng.normal(1.2, 0.1)) if valued else None,
                    "fmep_sigma_bar": 0.05 if valued else None,
                    "friction_torque_mean_nm": float(rng.normal(80, 5)) if valued else None,
                    "friction_torque_sigma_nm": 3.0 if valued else None,
                    "coefficients": {"a0": float(rng.normal()), "a1": None},
                    "coefficient_sigmas": {"a0": 0.1, "a1": None},
                    "data_weight": float(rng.uniform()), "status": status,
                    "reason": None if status == "measured" else f"because {status}", "flags": []})
    return out


def alert(alert_id: int, state: str = "active", cylinder: int | None = 3, kind: str = "ring_wear") -> dict:
    return {"alert_id": alert_id, "cylinder": cylinder, "kind": kind, "severity": "warning", "state": state,
            "raised_cycle": 100 + alert_id, "raised_at_s": 8.0 + alert_id, "cleared_cycle": None,
            "acknowledged_by": None, "message": f"cylinder {cylinder}: friction up",
            "evidence": {"fmep_bar": 1.4, "baseline_fmep_bar": 1.1, "cycles": [100, 150]}}
