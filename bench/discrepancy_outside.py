"""The discrepancy matrix's cases outside the workflow's library (issue 27, design note 101): the plant's engine record
edited where no effect holds it, and how such a row is judged.

A hidden truth named PLANT + "inertia" is no simulator effect: the plant simulates an engine record whose node
inertia (``node``: "flywheel" or "load", the record's flywheel_node / load_node) is ``scale`` times the record's,
while the monitor's model keeps the record as written (the flywheel node's is an effect since design note 109,
flywheel_inertia; the matrix's flywheel cases use it, this edit stays for the load node's).
``plant_spec`` makes that record, ``effects_of`` keeps the truths that are simulator effects.

Judged (bench_discrepancy.judge, a label holding OUTSIDE): right = nothing named, and the outcome says a discrepancy
(unexplained or ambiguous); "silent" = nothing named and "no significant missing effect" (honest only where the
hidden effect leaves nothing beyond a healthy log's gap: the row's gap beside the healthy row's of the same
point and seed, ``summarise``); named = something named for an effect the log does not hold (wrong); held-out worse =
a named model whose held-out gap is larger than the baseline's.
"""

from __future__ import annotations

import dataclasses

from frictionwatch.core.model.engine_spec import EngineSpec

PLANT = "plant:"  # a hidden truth that edits the plant's engine record (no effect of core.model.effects)
OUTSIDE = "(not in library)"  # the label mark of a case the workflow has no candidate for


def plant_truth(node: str, scale: float) -> tuple:
    """A hidden truth (as discrepancy_cases._t) that scales one node's inertia in the plant only; not judged on a
    parameter (nothing in the library can name it)."""
    return (PLANT + "inertia", {"node": node, "scale": scale}, None, None)


def effects_of(truths) -> list[tuple[str, dict]]:
    """The (name, params) of the hidden truths that are simulator effects."""
    return [(name, params) for name, params, *_ in truths if not name.startswith(PLANT)]


def plant_spec(spec: EngineSpec, truths) -> EngineSpec:
    """The engine record the plant simulates: ``spec`` with each PLANT + "inertia" truth applied (a node's inertia
    times its scale); ``spec`` itself when there is none."""
    inertia = spec.node_inertia.astype(float).copy()
    edited = False
    for name, params, *_ in truths:
        if name != PLANT + "inertia":
            continue
        node = {"flywheel": spec.flywheel_node, "load": spec.load_node}[params["node"]]
        inertia[node] *= float(params["scale"])
        edited = True
    return dataclasses.replace(spec, node_inertia=inertia) if edited else spec


def judge_outside(named: bool, outcome: str | None, gap_before: float, gap_after: float) -> dict:
    """A row's fields for a case outside the library (module doc), from whether anything was named, the outcome and
    the held-out gap before and after: how it was said and whether the held-out gap grew."""
    said = outcome in ("unexplained", "ambiguous")
    return {"outside": "named" if named else ("said" if said else "silent"),
            "outside_right": (not named) and said, "heldout_worse": bool(named and gap_after > gap_before)}


def summarise_outside(rows: list[dict]) -> dict:
    """Totals over the outside-library rows: right (said, nothing named), silent, named (wrong), held-out worse, and
    each silent row's gap beside the healthy row's of the same engine, point and seed (where one is in ``rows``)."""
    out = [r for r in rows if "outside" in r]
    healthy = {(r.get("engine"), r["rpm"], r["load"], r["seed"]): r["gap_before"] for r in rows
               if r["case"] == "none" and "rpm" in r}
    silent = [{"case": r["case"], "engine": r.get("engine"), "rpm": r["rpm"], "seed": r["seed"],
               "gap": r["gap_before"], "healthy_gap": healthy.get((r.get("engine"), r["rpm"], r["load"], r["seed"]))}
              for r in out if r["outside"] == "silent"]
    return {"rows": len(out), "right": sum(r["outside_right"] for r in out),
            "silent": len(silent), "named": sum(r["outside"] == "named" for r in out),
            "heldout_worse": sum(bool(r["heldout_worse"]) for r in out),
            "named_list": [f"{r['case']} {r.get('engine')} {r['rpm']:g} s{r['seed']} -> "
                           + ", ".join(f"{e}[{c}]" for e, c in r["all"]) for r in out if r["outside"] == "named"],
            "silent_list": silent}
