"""Rows of the service contract (dicts) to and from the store's columns, the same for every backend.

Known keys go to their columns, any other key a helper added to the contract later to an ``extra`` JSON column, so a
row reads back as it was written. Lists and dicts are JSON text. Non-finite numbers become NULL / None (the
project's convention: a value the data cannot give is None, never a number).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

CYCLE_COLUMNS = ("t_start_s", "rpm_mean", "load_torque_nm", "load_power_kw", "imep_bar", "pmax_bar",
                 "friction_balance_nm", "flags")
LOSS_COLUMNS = ("fmep_bar", "fmep_sigma_bar", "friction_torque_mean_nm", "friction_torque_sigma_nm", "coefficients",
                "coefficient_sigmas", "data_weight", "status", "reason", "flags")
JSON_COLUMNS = frozenset({"imep_bar", "pmax_bar", "flags", "coefficients", "coefficient_sigmas"})
ALERT_STATES = ("active", "acknowledged", "cleared")


class StoreError(Exception):
    """An expected failure of the store, said in one line (a newer schema, a malformed row, an unknown engine)."""


def finite(value: Any) -> Any:
    """Non-finite floats -> None, through lists and dicts (numpy scalars become floats)."""
    if isinstance(value, dict):
        return {str(k): finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [finite(v) for v in value]
    if isinstance(value, np.ndarray):
        return finite(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def json_text(value: Any) -> str:
    """Compact JSON with non-finite numbers as null."""
    try:  # the common case: plain JSON, all numbers finite (the contract's dicts)
        return json.dumps(value, separators=(",", ":"), allow_nan=False)
    except (TypeError, ValueError):  # numpy values, NaN or inf somewhere: the slow walk
        try:
            return json.dumps(finite(value), separators=(",", ":"), allow_nan=False)
        except (TypeError, ValueError) as e:
            raise StoreError(f"not JSON: {e}") from None


def column_value(name: str, value: Any) -> Any:
    """What goes in column ``name``: JSON text, a string, None, or a finite float (NaN and inf as None)."""
    if name in JSON_COLUMNS:
        return json_text(value)
    if isinstance(value, str) or value is None:
        return value
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise StoreError(f"{name} is not a number: {value!r:.60}") from None
    return v if math.isfinite(v) else None


def from_columns(names: Sequence[str], values: Sequence) -> dict:
    return {n: json.loads(v) if n in JSON_COLUMNS else v for n, v in zip(names, values)}


def extra_fields(text: str | None) -> dict:
    return json.loads(text) if text else {}


def take(row: dict, names: Sequence[str], what: str) -> list:
    missing = [n for n in names if n not in row]
    if missing:
        raise StoreError(f"{what} lacks {', '.join(missing)}")
    return [column_value(n, row[n]) for n in names]


def extra_text(row: dict, known: Sequence[str]) -> str | None:
    rest = {k: v for k, v in row.items() if k not in known}
    return json_text(rest) if rest else None


def cycle_params(engine_id: str, version: int, row: dict, now: float) -> tuple:
    if "cycle_index" not in row:
        raise StoreError("cycle row lacks cycle_index")
    values = take(row, CYCLE_COLUMNS, f"cycle row {row['cycle_index']}")
    known = ("engine_id", "cycle_index", "model_version", *CYCLE_COLUMNS)
    return (engine_id, int(row["cycle_index"]), version, *values, extra_text(row, known), now)


def loss_params(engine_id: str, cycle_index: int, row: dict, now: float) -> tuple:
    if "cylinder" not in row:
        raise StoreError(f"estimate row of cycle {cycle_index} lacks cylinder")
    values = take(row, LOSS_COLUMNS, f"estimate row of cycle {cycle_index} cylinder {row['cylinder']}")
    known = ("engine_id", "cycle_index", "cylinder", *LOSS_COLUMNS)
    return (engine_id, cycle_index, int(row["cylinder"]), *values, extra_text(row, known), now)


def alert_params(engine_id: str, alert: dict, now: float) -> tuple:
    missing = [k for k in ("alert_id", "kind", "severity", "state") if k not in alert]
    if missing:
        raise StoreError(f"alert lacks {', '.join(missing)}")
    if alert["state"] not in ALERT_STATES:
        raise StoreError(f"alert {alert['alert_id']}: unknown state {alert['state']!r}")
    cyl, raised = alert.get("cylinder"), alert.get("raised_cycle")
    return (engine_id, int(alert["alert_id"]), None if cyl is None else int(cyl), str(alert["kind"]),
            str(alert["severity"]), str(alert["state"]), None if raised is None else int(raised),
            json_text({**alert, "engine_id": engine_id}), now)
