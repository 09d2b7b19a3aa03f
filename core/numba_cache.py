"""One numba on-disk cache per version of the kernels' sources.

    use_fingerprinted_cache()   # core/__init__.py, before any kernel is decorated (drivers import core first)

Why: numba checks a cached kernel against its own file only (the index's stamp is that file's modification time and
size). A kernel that calls a kernel of another module keeps running the old compiled callee after that module
changed -- a silently stale number after an upgrade (seen: the tooth fit still ran the old inverse after
spd_kernels.py changed, design notes 52; results off by 1e-12 after an earlier change). So the cache lives in a
folder named by a fingerprint of every source file of core/ and drivers/ (where every kernel lives): any change there
starts a fresh folder, compiled once; an unchanged tree finds its kernels as before.

Where: ``$NUMBA_CACHE_DIR/frictionwatch-<fingerprint>`` when NUMBA_CACHE_DIR is set (the Docker image, the benches),
else ``$XDG_CACHE_HOME`` or ``~/.cache``, ``frictionwatch/numba/<fingerprint>``. Where that cannot be written, numba's
own default stays (beside the sources), said once in the log. Folders of earlier versions are left where they are
(``make clean-numba`` removes them): a few tens of MB each.

    use_optimisation_level()    # core/__init__.py, first: LLVM's -O1 for our kernels unless NUMBA_OPT says otherwise

Why: the cold compile (~41 s on a quiet box, target <= 40 s) is ~9 % shorter at -O1 than at numba's default -O3
with the same figures (every outcome equal within rtol 1e-12; 0 of ~2.05 M numbers differ) and no per-cycle cost
beyond the noise (design note 98, bench/compile_opt.py). Set in the environment, not only in ``numba.config``:
numba re-reads every NUMBA_* variable whenever one of them changes (``config.reload_config`` at each compile), which
would put a value set in ``config`` alone back to -O3; the processes we start inherit it. A caller's NUMBA_OPT wins;
the level is part of the cache folder's fingerprint, so kernels compiled at one level are never loaded at another.

    pause_gc_while_compiling()  # core/__init__.py too: Python's garbage collector off during each numba compile

Why: a cold compile builds and drops a few hundred thousand small objects (numba's IR, types, LLVM wrappers);
Python's generational collector ran ~25 full collections over a ~440k-object heap during the monitor's first run,
~3.4 s of a ~48 s cold compile (design note 67, bench/compile_events.py). Off for the outermost compile, on again at
its end (an exception included: numba ends the event in a ``finally``), so nothing is left uncollected for long: the
next collection after the compile takes what it dropped. numba emits the event under its global compiler lock, so
compiles never overlap and one depth count serves every thread. A collector that was off before stays off.

    name_cache_entries_by_key()  # core/__init__.py too: each cached kernel's file named by its key, index last

Why: numba's cache (0.68, caching.IndexDataCacheFile.save) names a new entry's file by the first number its index
does not use yet, writes the index, then the file. Two processes compiling two specialisations of one kernel into one
cache folder at once (``make test``'s two workers on a cold cache, a child compiling beside serve) can both read the
index before either writes it and both take number 1: the index then says one signature while the file holds the
other's code, and every later process loads that code for the wrong argument types, a silently wrong number (seen:
a toy ``f(x) = 2x + 1`` cached for int64 and float64 at once returned 7 for f(3.5), design note 150). Named by a
digest of its key, an entry's file holds only that key's code; written before the index, no index points at a file
not written yet. What is left of the race is an index entry lost when two processes rewrite one index at once: a
miss, compiled again when next called.
"""

from __future__ import annotations

import gc
import hashlib
import logging
import os
import tempfile
from pathlib import Path

from numba import config
from numba.core import event

log = logging.getLogger(__name__)

PACKAGES = ("core", "drivers")  # the folders (installed as frictionwatch.core, frictionwatch.drivers) with kernels

# LLVM's optimisation level (NUMBA_OPT) for our kernels. Measured (design note 98, bench/compile_opt.py, two rounds
# alternated, fresh processes, empty caches, load 1.0-2.2): the cold compile at 1 / at 3 = 0.913, 0.912 (40.9 -> 37.3
# s at load 1.0), the cold process's CPU 0.928, 0.922; per-cycle CPU 1.016-1.018 (median of 2 rounds; the first round
# +2-4 %, the second -1 %) and 0.98-0.99 in an earlier run of 2 rounds: within the noise. This code against a
# caller's NUMBA_OPT=3 (2 rounds, load 1.0): 0.909, 0.879; per cycle 0.98-1.00; every outcome equal within rtol
# 1e-12. 2 is not shorter than 3 (0.96, 1.35 at load 3-5); 0 is 0.76-1.00 but 4-13x slower a cycle; loop
# vectorisation off or the target machine at 0 cost 2-40 % a cycle and change the fastmath kernels' figures.
OPT_LEVEL = "1"


def source_digest(root: Path, packages: tuple[str, ...] = PACKAGES, salt: bytes = b"") -> str:
    """SHA-256 (hex) of ``salt`` and every ``*.py`` file under each of ``root``/``packages``, by relative path and
    content (~5 ms for core/ and drivers/; content, not modification times, so that a copy or a checkout with other
    times keeps its cache). Also the monitor state's code fingerprint (service/monitor_snapshot.py)."""
    h = hashlib.sha256(salt)
    for package in packages:
        base = root / package
        if not base.is_dir():
            raise FileNotFoundError(f"{base} not found beside {Path(__file__).name}")
        for path in sorted(base.rglob("*.py")):
            h.update(path.relative_to(root).as_posix().encode())
            h.update(b"\0")
            h.update(path.read_bytes())
    return h.hexdigest()


def source_fingerprint(root: Path, salt: bytes = b"") -> str:
    """16 hex digits of ``source_digest`` of core/ and drivers/ under ``root`` (and ``salt``: the compile settings,
    ``compile_settings``): the cache folder's name."""
    return source_digest(root, salt=salt)[:16]


def use_optimisation_level(level: str = OPT_LEVEL, environ: dict | None = None) -> str:
    """NUMBA_OPT = ``level`` for every kernel compiled after this call, unless already set (the caller's wins; module
    doc); returns the level in force."""
    env = os.environ if environ is None else environ
    if "NUMBA_OPT" not in env:
        env["NUMBA_OPT"] = level
        if environ is None:
            config.reload_config()
    return str(env["NUMBA_OPT"])


def compile_settings() -> bytes:
    """What numba compiles with beside the sources, as the cache folder's fingerprint salt: the optimisation level
    and the vectorisers (a kernel compiled under other settings is not loaded)."""
    return f"opt={config.OPT!r};loop={config.LOOP_VECTORIZE};slp={config.SLP_VECTORIZE}".encode()


def fingerprinted_cache_dir(fingerprint: str, environ: dict | None = None) -> Path:
    """Where the cache of this source version lives (module docstring)."""
    env = os.environ if environ is None else environ
    if env.get("NUMBA_CACHE_DIR"):
        return Path(env["NUMBA_CACHE_DIR"]) / f"frictionwatch-{fingerprint}"
    user = Path(env["XDG_CACHE_HOME"]) if env.get("XDG_CACHE_HOME") else Path.home() / ".cache"
    return user / "frictionwatch" / "numba" / fingerprint


def use_fingerprinted_cache() -> None:
    """Point numba's cache at this source version's folder (idempotent; a no-op with the JIT disabled)."""
    if config.DISABLE_JIT:
        return
    root = Path(__file__).resolve().parents[1]  # the checkout (editable) or site-packages/frictionwatch
    fingerprint = source_fingerprint(root, compile_settings())
    if str(config.CACHE_DIR or "").rstrip("/").endswith(fingerprint):
        return
    target = fingerprinted_cache_dir(fingerprint)
    try:
        target.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=target).close()
    except OSError as exc:
        log.warning("numba cache: %s cannot be written (%s); numba's default place is used, which does not see a "
                    "changed callee in another file", target, exc)
        return
    config.CACHE_DIR = str(target)


class CompileGcPause(event.Listener):
    """Python's garbage collector off while numba compiles (module doc); ``depth``: compiles in progress (nested)."""

    def __init__(self) -> None:
        self.depth = 0
        self._was_enabled = False

    def on_start(self, ev: event.Event) -> None:
        if self.depth == 0:
            self._was_enabled = gc.isenabled()
            gc.disable()
        self.depth += 1

    def on_end(self, ev: event.Event) -> None:
        self.depth -= 1
        if self.depth == 0 and self._was_enabled:
            gc.enable()


def pause_gc_while_compiling() -> CompileGcPause:
    """Register a ``CompileGcPause`` for numba's compile events (once, from core/__init__.py) and return it."""
    listener = CompileGcPause()
    event.register("numba:compile", listener)
    return listener


def name_cache_entries_by_key() -> bool:
    """numba's cache entries each in a file named by a digest of its key, written before the index entry that
    points at it (module doc); everything else as numba's own ``IndexDataCacheFile.save`` (its index and data
    writers, each an atomic rename). False, numba's own way kept and said once in the log, where this numba's cache
    file lacks what this relies on."""
    from numba.core import caching

    cache_file = getattr(caching, "IndexDataCacheFile", None)
    numbas = getattr(cache_file, "save", None)
    if getattr(numbas, "keyed", False):
        return True
    if numbas is None or not all(hasattr(cache_file, n) for n in ("_load_index", "_save_index", "_save_data",
                                                                  "_dump")):
        log.warning("numba cache: this numba's cache files differ from 0.68's; two processes compiling one kernel "
                    "into one cache at once may pair an index entry with another signature's code")
        return False

    def save(self, key, data) -> None:
        pattern = getattr(self, "_data_name_pattern", "")
        if "{number:d}" not in pattern:
            return numbas(self, key, data)
        # the key as numba pickles it into the index (its signature, the target machine, the bytecode's hash)
        name = pattern.replace("{number:d}", hashlib.sha256(self._dump(key)).hexdigest()[:16])
        self._save_data(name, data)
        overloads = self._load_index()
        if overloads.get(key) != name:
            overloads[key] = name
            self._save_index(overloads)
        return None

    save.keyed = True
    cache_file.save = save
    return True


__all__ = ["OPT_LEVEL", "CompileGcPause", "compile_settings", "fingerprinted_cache_dir", "name_cache_entries_by_key",
           "pause_gc_while_compiling", "source_digest", "source_fingerprint", "use_fingerprinted_cache",
           "use_optimisation_level"]
