"""The suite's numba kernels compiled once between `make test`'s workers, not once in each.

Why: on a fresh clone (CI, a new machine) the numba cache is empty, and each xdist worker compiled every kernel it
met on its own: ~130 s each, ~75 % of the suite's first minutes, the same work twice (design note 121). Each worker
now compiles its share of the kernels the suite is known to use (``kernel_manifest.pkl``: every kernel
specialisation the suite compiled, in the order it compiled them, callees before their callers) before its first
test; numba's on-disk cache is shared by the processes, so each worker then loads the other's share from it instead
of compiling it again.

The manifest only saves time: a kernel missing from it compiles when first called, as before, and an entry that no
longer fits its kernel (the code changed since it was recorded) is counted and skipped. Its numbers are the same
either way: the same specialisations are compiled, earlier. Recorded by a whole run of the suite on an empty cache:

    NUMBA_CACHE_DIR=$(mktemp -d) FW_KERNEL_MANIFEST=record make test

(each process appends to its own part as it compiles; the controller merges them into ``kernel_manifest.pkl`` at
the end; ``python -m tests.kernel_manifest`` merges the parts a stopped run left).
"""

from __future__ import annotations

import importlib
import os
import pickle
import sys
import time
from pathlib import Path

MANIFEST = Path(__file__).with_name("kernel_manifest.pkl")
RECORD = os.environ.get("FW_KERNEL_MANIFEST") == "record"
PACKAGE = "frictionwatch."


def _identity() -> dict:
    """What a manifest's pickled numba types depend on: another numba or Python cannot be trusted to read them."""
    import numba

    return {"numba": numba.__version__, "python": list(sys.version_info[:2])}


class Recorder:
    """numba's compile events of our kernels, each appended to ``path`` as one pickle of (module, qualified name,
    argument types, seconds) as its compile ends (a callee's inside its caller's ends first), so a run stopped early
    still leaves what it compiled; nested functions cannot be found by name and are left out, and so are types numba
    cannot pickle (those kernels compile when first called, as before).

    The seconds are the entry's own: its compile event's wall time less the compile events of our kernels nested
    in it (those are entries of their own); numba's own overloads compiled inside it stay in it, as they would when
    a worker compiles the entry. ``compile_share`` deals the entries by them."""

    def __init__(self, path: Path, package: str = PACKAGE):
        from numba.core import event

        recorder = self
        self.package = package  # whose kernels are recorded (a test records its own, not the suite's)
        self.open: list[list[float]] = []  # per event in progress: its start, and the seconds of our kernels in it

        class Listener(event.Listener):
            def on_start(self, ev) -> None:
                recorder.open.append([time.perf_counter(), 0.0])

            def on_end(self, ev) -> None:
                recorder.on_end(ev)

        self.part = path.open("wb")
        self.listener = Listener()
        event.register("numba:compile", self.listener)

    def close(self) -> None:
        from numba.core import event

        event.unregister("numba:compile", self.listener)
        self.part.close()

    def on_end(self, ev) -> None:
        start, nested = self.open.pop() if self.open else (time.perf_counter(), 0.0)
        seconds = time.perf_counter() - start
        func = getattr(ev.data.get("dispatcher"), "py_func", None)
        ours = func is not None and func.__module__.startswith(self.package) and "<locals>" not in func.__qualname__
        if self.open:  # our kernel's whole time counts as nested in its caller; numba's passes its own nested on
            self.open[-1][1] += seconds if ours else nested
        if not ours:
            return
        try:
            row = pickle.dumps((func.__module__, func.__qualname__, tuple(ev.data.get("args") or ()),
                                round(max(seconds - nested, 0.0), 3)), protocol=4)
        except Exception:
            return
        self.part.write(row)
        self.part.flush()


def _rows(part: Path) -> list[tuple]:
    rows = []
    with part.open("rb") as f:
        while True:
            try:
                rows.append(pickle.load(f))
            except (EOFError, pickle.UnpicklingError):  # the end, or a row cut by a run killed mid-write
                return rows  # what came before it stands


def merge(parts: list[Path], path: Path = MANIFEST) -> int:
    """The recording processes' parts as one manifest (each kernel once, in the first part's order, then the others'
    new ones), written whole or not at all; the parts removed. The number of kernels written."""
    seen, kernels = set(), []
    for part in parts:
        for kernel in _rows(part):
            key = (kernel[0], kernel[1], pickle.dumps(kernel[2], protocol=4))
            if key not in seen:
                seen.add(key)
                kernels.append(kernel)
    tmp = path.with_suffix(".tmp")
    tmp.write_bytes(pickle.dumps({**_identity(), "kernels": kernels}, protocol=4))
    tmp.replace(path)
    for part in parts:
        part.unlink()
    return len(kernels)


def parts() -> list[Path]:
    return sorted(MANIFEST.parent.glob("kernel_manifest.*.part"))


def load(path: Path = MANIFEST) -> list[tuple]:
    """The manifest's kernels; none where it is missing or was recorded under another numba or Python."""
    try:
        doc = pickle.loads(path.read_bytes())
    except (OSError, pickle.UnpicklingError, AttributeError, ImportError, EOFError):
        return []
    if {k: doc.get(k) for k in ("numba", "python")} != _identity():
        return []
    return [k for k in doc["kernels"] if k[0].startswith(PACKAGE)]  # the product's: a test's own compile afresh


def _kernel(module: str, qualname: str):
    kernel = importlib.import_module(module)
    for part in qualname.split("."):
        kernel = getattr(kernel, part)
    return kernel


def _callees(kernel) -> set:
    """The numba dispatchers ``kernel`` calls, directly or through others: the global names its Python code reads
    that are dispatchers (a kernel calls another by its module-level name), followed transitively."""
    from numba.core.dispatcher import Dispatcher

    found, todo = set(), [kernel]
    while todo:
        func = getattr(todo.pop(), "py_func", None)
        for name in getattr(getattr(func, "__code__", None), "co_names", ()):
            callee = func.__globals__.get(name)
            if isinstance(callee, Dispatcher) and callee not in found:
                found.add(callee)
                todo.append(callee)
    return found


def deal(costs: dict[int, float], count: int) -> dict[int, int]:
    """Each entry's worker: in the recorded order (callees first), to the worker with the least compile seconds dealt
    so far, so the shares take about the same time wherever the order put the few large kernels (the plant's
    `advance`, the first LAPACK solve: 10-20 s each at load). Every worker computes the same dealing from the same
    manifest."""
    dealt, owner = [0.0] * count, {}
    for i in sorted(costs):
        owner[i] = min(range(count), key=lambda w: (dealt[w], (w - i) % count))
        dealt[owner[i]] += costs[i]
    return owner


def compile_share(kernels: list[tuple], index: int, count: int, done: Path | None = None,
                  patience_s: float = 120.0) -> dict:
    """Compile (or load from the cache) this worker's share of the manifest's kernels: the ``index``-th of ``count``
    shares dealt by recorded compile seconds (``deal``; a manifest recorded without them deals in turn, each entry
    one second). Returns the counts and seconds for the run's summary.

    ``done``: a folder the workers share, where each marks the entries it has compiled. A kernel whose callees
    (earlier entries of the kernels it calls) are another worker's waits for their marks, this worker compiling its
    next ready kernel meanwhile: compiled before they are in the cache, numba compiles the callees again inside the
    caller, the same work in both workers (design note 127). Once this worker has idled ``patience_s`` in all
    waiting (the other died or went slow), the rest compile at once, as without ``done``. Kernels with an explicit
    signature compile when their module is imported (numba refuses ``compile`` on them) and are counted apart."""
    t0, counts = time.perf_counter(), {"compiled": 0, "at_import": 0, "stale": 0}
    entries, waits, costs = {}, {}, {}
    for i, (module, qualname, args, *seconds) in enumerate(kernels):
        try:
            entries[i] = (_kernel(module, qualname), args)
        except Exception:  # the kernel is gone or renamed since the manifest was recorded
            counts["stale"] += i % count == index
            continue
        costs[i] = seconds[0] if seconds else 1.0
    owner = deal(costs, count)
    mine = [i for i in entries if owner[i] == index]
    counts["dealt_s"] = round(sum(costs[i] for i in mine), 1)
    if done is not None:
        done.mkdir(parents=True, exist_ok=True)
        by_kernel: dict = {}
        for i, (kernel, _) in entries.items():
            by_kernel.setdefault(kernel, []).append(i)
        for i in mine:
            waits[i] = {j for callee in _callees(entries[i][0]) for j in by_kernel.get(callee, ())
                        if j < i and owner[j] != index}
    idle = 0.0
    while mine:
        ready = next((i for i in mine if not waits.get(i) or idle >= patience_s
                      or all((done / str(j)).exists() for j in waits[i])), None)
        if ready is None:
            time.sleep(0.05)
            idle += 0.05
            continue
        mine.remove(ready)
        kernel, args = entries[ready]
        try:
            if getattr(kernel, "_can_compile", True):
                kernel.compile(args)
                counts["compiled"] += 1
            else:
                counts["at_import"] += 1
        except Exception:  # the code changed since the manifest was recorded: compiled when first called instead
            counts["stale"] += 1
        if done is not None:
            (done / str(ready)).touch()
    return {**counts, "seconds": round(time.perf_counter() - t0, 1), "waited": round(idle, 1)}


if __name__ == "__main__":
    print(f"{merge(parts())} kernels in {MANIFEST}")
