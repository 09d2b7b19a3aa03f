"""One numba cache per version of the kernels' sources (core/numba_cache.py): a change in any file of core/ or
drivers/ moves every kernel to a fresh folder, so a kernel never runs a stale compiled callee of another file."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from frictionwatch.core.numba_cache import (
    OPT_LEVEL,
    compile_settings,
    fingerprinted_cache_dir,
    source_fingerprint,
    use_optimisation_level,
)


def _tree(tmp_path: Path) -> Path:
    for rel, text in {"core/a.py": "x = 1\n", "core/sub/b.py": "y = 2\n", "drivers/c.py": "z = 3\n",
                      "service/d.py": "w = 4\n"}.items():
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text(text)
    return tmp_path


def test_the_fingerprint_follows_every_kernel_source_file_and_nothing_else(tmp_path: Path) -> None:
    root = _tree(tmp_path)
    first = source_fingerprint(root)
    assert first == source_fingerprint(root) and len(first) == 16
    (root / "service/d.py").write_text("w = 5\n")  # no kernel lives in service/
    assert source_fingerprint(root) == first
    os.utime(root / "core/a.py", (0, 0))  # times alone: the same sources
    assert source_fingerprint(root) == first
    (root / "core/sub/b.py").write_text("y = 3\n")  # a callee in another file
    second = source_fingerprint(root)
    assert second != first
    (root / "drivers/e.py").write_text("")  # a new file
    assert source_fingerprint(root) not in (first, second)


def test_the_optimisation_level_is_ours_unless_the_caller_set_one() -> None:
    env: dict = {}
    assert use_optimisation_level(environ=env) == OPT_LEVEL and env == {"NUMBA_OPT": OPT_LEVEL}
    env = {"NUMBA_OPT": "3"}
    assert use_optimisation_level(environ=env) == "3" and env == {"NUMBA_OPT": "3"}


def test_numba_compiles_at_that_level_in_a_folder_of_its_own(tmp_path: Path) -> None:
    code = ("import json, os, numba\n"
            "import frictionwatch.core\n"
            "from numba.core.registry import cpu_target\n"
            "cpu_target.target_context.codegen()  # the target machine, made now: after core set the level\n"
            "print(json.dumps([int(numba.config.OPT), os.environ['NUMBA_OPT'], numba.config.CACHE_DIR]))\n")
    seen = []
    for extra in ({}, {"NUMBA_OPT": "3"}):
        env = {k: v for k, v in os.environ.items() if k != "NUMBA_OPT"} | {"NUMBA_CACHE_DIR": str(tmp_path), **extra}
        out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
        seen.append(json.loads(out.stdout))
    assert seen[0][:2] == [int(OPT_LEVEL), OPT_LEVEL] and seen[1][:2] == [3, "3"]
    assert seen[0][2] != seen[1][2]  # kernels compiled at one level are not loaded at the other


def test_the_folder_under_numba_cache_dir_or_the_user_cache() -> None:
    assert fingerprinted_cache_dir("abc", {"NUMBA_CACHE_DIR": "/x/nb"}) == Path("/x/nb/frictionwatch-abc")
    assert fingerprinted_cache_dir("abc", {"XDG_CACHE_HOME": "/y"}) == Path("/y/frictionwatch/numba/abc")
    assert fingerprinted_cache_dir("abc", {}) == Path.home() / ".cache/frictionwatch/numba/abc"


def test_a_kernel_is_cached_in_this_source_versions_folder(tmp_path: Path) -> None:
    code = ("import json, numba\n"
            "from frictionwatch.core.monitor.identify import spd\n"
            "from frictionwatch.drivers.assembly import frame_kernels\n"
            "print(json.dumps([numba.config.CACHE_DIR, spd.cho_solve._cache._cache_path,\n"
            "                  frame_kernels.frame_rows._cache._cache_path]))\n")
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    cache_dir, core_kernel, driver_kernel = json.loads(out.stdout)
    import frictionwatch.core

    installed = Path(frictionwatch.core.__file__).resolve().parents[1]
    expected = tmp_path / f"frictionwatch-{source_fingerprint(installed, compile_settings())}"
    assert Path(cache_dir) == expected
    assert Path(core_kernel).is_relative_to(expected) and Path(driver_kernel).is_relative_to(expected)


def test_the_garbage_collector_is_paused_while_numba_compiles_and_back_after():
    """core/__init__.py registers CompileGcPause: a listener registered after it sees the collector off at each
    compile's start; after the compile it is on again, and a collector that was off before stays off."""
    import gc

    from numba import njit
    from numba.core import event

    seen: list[bool] = []

    class Probe(event.Listener):
        def on_start(self, ev):
            seen.append(gc.isenabled())

        def on_end(self, ev):
            pass

    probe = Probe()
    event.register("numba:compile", probe)
    try:
        assert gc.isenabled()

        @njit(cache=False)
        def plus_one(x):
            return x + 1

        assert plus_one(1) == 2
        assert seen and not any(seen)  # off at every compile's start (nested ones included)
        assert gc.isenabled()
        gc.disable()
        try:
            assert plus_one(1.5) == 2.5  # a second specialisation compiled while the collector was off
            assert not gc.isenabled()
        finally:
            gc.enable()
    finally:
        event.unregister("numba:compile", probe)


def test_two_processes_caching_two_signatures_of_one_kernel_at_once_keep_each_with_its_own_code(tmp_path: Path):
    """numba's cache index and files as two processes leave them when each caches another specialisation of one
    kernel at the same moment (design note 150), played by two threads over two cache-file objects of one folder:
    both read the index before either writes it, b writes it last and a's file lands last. Numba 0.68's own naming
    gave both entries file 1, the index pointing the second key at the first key's code (the toy kernel's
    f(3.5) = 7); named by key (core/numba_cache.py ``name_cache_entries_by_key``, applied at core's import), an entry
    loads its own code or nothing (a miss: compiled again), never another key's."""
    import threading
    import time

    from numba.core.caching import IndexDataCacheFile  # its save replaced at core's import (this file imports core)

    both_read = threading.Barrier(2, timeout=10)

    class Racing(IndexDataCacheFile):
        def __init__(self, late_index_s: float, late_data_s: float) -> None:
            super().__init__(str(tmp_path), "kernels.f-1.py311", source_stamp=(1.0, 10))
            self.late_index_s, self.late_data_s = late_index_s, late_data_s

        def _load_index(self):
            overloads = super()._load_index()
            if not getattr(self, "read_once", False):
                self.read_once = True
                both_read.wait()  # each has read the index; neither has written it
            return overloads

        def _save_index(self, overloads):
            time.sleep(self.late_index_s)
            super()._save_index(overloads)

        def _save_data(self, name, data):
            time.sleep(self.late_data_s)
            super()._save_data(name, data)

    keys = {"a": (("int64",), "cpu"), "b": (("float64",), "cpu")}
    files = {"a": Racing(late_index_s=0.0, late_data_s=0.3), "b": Racing(late_index_s=0.1, late_data_s=0.0)}
    threads = [threading.Thread(target=files[k].save, args=(keys[k], f"code for {k}")) for k in keys]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    loaded = {k: IndexDataCacheFile(str(tmp_path), "kernels.f-1.py311", (1.0, 10)).load(keys[k]) for k in keys}
    assert all(loaded[k] in (f"code for {k}", None) for k in keys), loaded
    assert any(loaded[k] is not None for k in keys)  # what the last index writer saved is there
