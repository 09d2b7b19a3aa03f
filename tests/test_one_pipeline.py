"""Benches and tests run the product's one pipeline (issue 26 item 1), checked from the source with ast:

no bench/*.py or tests/**/*.py calls the monitor's loop pieces itself (``process_cycle``, ``initial_state``), builds
a ``CycleAssembler`` or feeds/flushes an assembler, except where ``ALLOWED`` says why (the unit tests of those very
pieces, and the assembler's own bench). Everything else goes through core.monitor.pipeline (``CyclePipeline``,
``run_cycles``) or service.pipeline (``EnginePipeline``, ``run``, ``analyze_records``, ``assembled_cycles``), so
its figures are measured on the path users run. ``test_the_check_sees_*`` tries the check on made-up sources, so a
check that can no longer fail shows too.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LOOP_PIECES = ("process_cycle", "initial_state", "CycleAssembler")  # calling any of these is running a loop of one's own
ASSEMBLER_MAKERS = ("CycleAssembler", "cycle_assembler", "assembler_for")  # what a name bound to an assembler came from
ASSEMBLER_NAMES = ("asm", "assembler")  # names (and attributes) taken to hold an assembler
ASSEMBLER_METHODS = ("feed", "flush")

# file (relative to the repository) -> why it may call the pieces: the unit tests of the pieces themselves
ALLOWED = {
    "tests/core/test_monitor.py": "the unit tests of process_cycle itself",
    "tests/core/test_monitor_state.py": "the unit tests of the monitor state (initial_state, process_cycle)",
    "tests/core/test_checks_interface.py": "the unit tests of process_cycle's checks (a spy check passed in)",
    "tests/drivers/test_cycles.py": "the unit tests of the cycle assembler",
    "tests/drivers/test_pressure_frames.py": "the assembler's tests on pressure frames and blocks",
    "tests/drivers/test_pressure_out_of_range.py": "the assembler's ingest limits (test_cycles' faults)",
    "tests/drivers/test_two_wheels.py": "the unit tests of the two-wheel assembler (its wheel2_missing counters)",
    "bench/common.py": "timed_assembly times the assembler alone (bench/bench_cycles.py)",
    # the tooth learner's step alone (fit_cycle_teeth from the initial state's learner), against the simulator's
    # true tooth errors: no monitor runs there (design note 60)
    "bench/tooth_learner_steps.py": "the tooth fit's learner step alone, cycle by cycle (no monitor)",
    "tests/core/test_tooth_learner_steps.py": "the tooth fit's learner step alone, cycle by cycle (no monitor)",
}


def _called_name(func: ast.expr) -> str | None:
    if isinstance(func, ast.Name):
        return func.id
    if isinstance(func, ast.Attribute):
        return func.attr
    return None


def own_loops(source: str, filename: str = "<source>") -> list[str]:
    """'file:line: what' for every call of a loop piece, every CycleAssembler built and every feed/flush on an
    assembler (a name bound from an assembler maker, named asm/assembler, or an attribute ``.assembler``) in
    ``source``; names imported under another name count as the piece."""
    tree = ast.parse(source, filename=filename)
    pieces = set(LOOP_PIECES)
    makers = set(ASSEMBLER_MAKERS)
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            for a in node.names:
                if a.asname and a.name in LOOP_PIECES:
                    pieces.add(a.asname)
                if a.asname and a.name in ASSEMBLER_MAKERS:
                    makers.add(a.asname)
    held = set(ASSEMBLER_NAMES)
    for node in ast.walk(tree):
        value = getattr(node, "value", None)
        if isinstance(node, (ast.Assign, ast.AnnAssign, ast.NamedExpr)) and isinstance(value, ast.Call) \
                and _called_name(value.func) in makers:
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            held |= {t.id for t in targets if isinstance(t, ast.Name)}
        elif isinstance(node, ast.arg) and node.annotation is not None and "CycleAssembler" in ast.unparse(
                node.annotation):
            held.add(node.arg)
    bad = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        name = _called_name(node.func)
        if name in pieces:
            bad.append(f"{filename}:{node.lineno}: calls {name}")
        elif name in ASSEMBLER_METHODS and isinstance(node.func, ast.Attribute):
            recv = node.func.value
            recv_name = recv.id if isinstance(recv, ast.Name) else recv.attr if isinstance(recv, ast.Attribute) \
                else None
            if recv_name in held or (isinstance(recv, ast.Call) and _called_name(recv.func) in makers):
                bad.append(f"{filename}:{node.lineno}: {name} on an assembler ({ast.unparse(node.func)})")
    return sorted(bad, key=lambda s: int(s.split(":")[1]))


def sources() -> list[Path]:
    return sorted([*(ROOT / "bench").glob("*.py"), *(ROOT / "tests").rglob("*.py")])


def test_benches_and_tests_run_the_pipeline():
    bad = []
    for path in sources():
        rel = path.relative_to(ROOT).as_posix()
        if rel not in ALLOWED:
            bad += own_loops(path.read_text(), rel)
    assert not bad, ("a loop of its own (run core.monitor.pipeline.CyclePipeline / run_cycles or "
                     "service.pipeline.EnginePipeline / run / assembled_cycles instead, or say in ALLOWED why not):\n"
                     + "\n".join(bad))


def test_every_allowed_file_exists_and_needs_it():
    """An entry of ALLOWED for a file gone or no longer calling a piece is stale."""
    stale = [rel for rel in ALLOWED if not (ROOT / rel).is_file() or not own_loops((ROOT / rel).read_text(), rel)]
    assert not stale, f"stale ALLOWED entries: {stale}"


def test_the_check_sees_a_monitor_loop_an_assembler_and_aliases():
    src = "\n".join([
        "from frictionwatch.core.monitor.monitor import initial_state, process_cycle as step",
        "from frictionwatch.drivers.assembly.cycles import CycleAssembler",
        "from frictionwatch.service.pipeline import cycle_assembler",
        "import frictionwatch.core.monitor.monitor as m",
        "a = CycleAssembler(info, 4, angles)",                       # 5
        "state = initial_state(spec)",                               # 6
        "state, res = step(spec, state, c)",                         # 7
        "state, res = m.process_cycle(spec, state, c)",              # 8
        "q = cycle_assembler(spec, info)",                           # 9
        "cycles = [c for r in recs for c in q.feed(r)] + q.flush()",  # 10: two
        "out = pipe.assembler.feed(r)",                              # 11
        "def f(x: CycleAssembler):",                                 # 12
        "    return x.flush()",                                      # 13
        "dec.feed(frames)",                                          # a decoder: not an assembler
        "pipe.outcomes(r)",                                          # the pipeline: fine
    ])
    lines = [int(s.split(":")[1]) for s in own_loops(src)]
    assert lines == [5, 6, 7, 8, 10, 10, 11, 13]


def test_the_check_passes_the_pipeline():
    src = "\n".join([
        "from frictionwatch.core.monitor.pipeline import CyclePipeline, run_cycles",
        "from frictionwatch.service.pipeline import EnginePipeline, assembled_cycles, run",
        "cycles, skipped = assembled_cycles(spec, info, records)",
        "pipe = CyclePipeline(spec, cfg)",
        "out = [pipe.process(c) for c in cycles]",
        "results = [o.result for o in run(spec, info, records) if o.ok]",
        "ep = EnginePipeline(spec, info)",
        "rs = [r for rec in records for r in ep.feed(rec)] + ep.flush()",
    ])
    assert own_loops(src) == []
