"""The kernel manifest's shares (tests/kernel_manifest.py): each entry's own compile seconds as recorded, the shares
dealt by them, a kernel's callees found through the kernels it calls, a kernel that calls another worker's waits for
that worker's mark (up to its patience), kernels with an explicit signature and entries that no longer fit are
counted apart."""

from __future__ import annotations

import time

import numba
import numpy as np
from numba import types

from tests import kernel_manifest, manifest_kernels

MODULE = manifest_kernels.__name__
INT = (types.int64,)


def test_each_entry_records_its_own_seconds_not_its_callees(tmp_path):
    # this test's own recorder: a recording run's (tests/conftest.py) keeps to the product's kernels, so these are
    # never in the manifest (once they were, a worker compiled them up front and this test saw no compile)
    recorder = kernel_manifest.Recorder(tmp_path / "m.part", package=manifest_kernels.__name__)
    suites = kernel_manifest.Recorder(tmp_path / "suite.part")  # as a recording run's: the product's kernels only
    try:
        t0 = time.perf_counter()
        manifest_kernels.top(np.uint16(3))  # a type no other test compiles: leaf, middle and top compile here
        wall = time.perf_counter() - t0
    finally:
        recorder.close()
        suites.close()
    assert kernel_manifest._rows(tmp_path / "suite.part") == []
    rows = kernel_manifest._rows(tmp_path / "m.part")
    assert [(r[1], r[2]) for r in rows] == [(name, (types.uint16,)) for name in ("leaf", "middle", "top")]
    seconds = [r[3] for r in rows]
    assert min(seconds) >= 0.0  # each its own: together no more than the one outer compile (rounding: 3 ms)
    assert sum(seconds) <= wall + 0.003 and sum(seconds) >= 0.5 * wall


def test_shares_are_dealt_by_recorded_seconds_and_in_turn_without_them():
    assert kernel_manifest.deal({0: 30.0, 1: 1.0, 2: 30.0, 3: 1.0}, 2) == {0: 0, 1: 1, 2: 1, 3: 0}  # 31 s each
    assert kernel_manifest.deal({i: 1.0 for i in range(5)}, 2) == {i: i % 2 for i in range(5)}
    assert kernel_manifest.deal({0: 1.0, 2: 1.0, 3: 1.0}, 3) == {0: 0, 2: 2, 3: 1}  # ties: the in-turn worker first


def test_a_kernels_callees_are_the_kernels_it_calls_directly_or_through_others():
    assert kernel_manifest._callees(manifest_kernels.top) == {manifest_kernels.middle, manifest_kernels.leaf}
    assert kernel_manifest._callees(manifest_kernels.middle) == {manifest_kernels.leaf}
    assert kernel_manifest._callees(manifest_kernels.leaf) == set()


def test_a_kernel_waits_for_its_callees_mark_from_the_other_worker(tmp_path, monkeypatch):
    kernels = [(MODULE, "leaf", INT), (MODULE, "top", INT)]  # worker 0 of 2 owns leaf, worker 1 top
    done, naps = tmp_path / "done", []

    def nap(seconds):  # the other worker, as seen from this one: leaf marked after this worker's third look
        naps.append(seconds)
        if len(naps) == 3:
            (done / "0").touch()

    monkeypatch.setattr(kernel_manifest.time, "sleep", nap)
    share = kernel_manifest.compile_share(kernels, 1, 2, done, patience_s=600.0)
    assert share["compiled"] == 1 and len(naps) == 3  # waited until the mark, not longer
    naps.clear()
    share = kernel_manifest.compile_share(kernels, 1, 2, done, patience_s=600.0)
    assert share["compiled"] == 1 and naps == []  # marked already: no wait
    share = kernel_manifest.compile_share(kernels, 1, 2, tmp_path / "never", patience_s=0.0)
    assert share["compiled"] == 1 and naps == []  # no patience: compiled at once, mark or not
    assert manifest_kernels.top(4) == 7


def test_a_worker_marks_what_it_compiled_and_waits_for_none_of_its_own(tmp_path):
    kernels = [(MODULE, "leaf", INT), (MODULE, "middle", INT), (MODULE, "top", INT)]
    share = kernel_manifest.compile_share(kernels, 0, 1, tmp_path, patience_s=60.0)
    assert (share["compiled"], share["at_import"], share["stale"]) == (3, 0, 0) and share["seconds"] < 60.0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["0", "1", "2"]


def test_explicit_signatures_and_gone_kernels_are_counted_apart(tmp_path):
    kernels = [(MODULE, "explicit", INT), (MODULE, "no_such_kernel", INT), (MODULE, "leaf", (types.float64,))]
    share = kernel_manifest.compile_share(kernels, 0, 1, tmp_path)
    assert (share["compiled"], share["at_import"], share["stale"]) == (1, 1, 1)
    assert numba.typeof(manifest_kernels.leaf(1.5)) == types.float64
