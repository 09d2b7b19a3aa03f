"""The monitor's carried state as text for the store, and back, without loading code from a shared database.

    text = dumps(pipeline.carried())         # pickled, compressed, base64 (about 1.2 MB for a genset-v20)
    carried = loads(text)                    # SnapshotError (one line) for anything but plain state
    fingerprint()                            # of the code the state was made by: core/ and the package version

What is written holds arrays and core/'s own classes only: ``CyclePipeline.carried`` leaves out what the model
rebuilds (its loss terms, whose reference functions are numba code). ``loads`` reads it with an unpickler that
resolves no name but core/'s classes, numpy's dtype and buffer constructor and a few builtin containers: constructing
a core class has no side effect (core/ opens no file, socket or clock), so a database that was tampered with can make
a wrong state, never run code. A state made by other code (another core/ or version) is not loaded: its classes may
have other fields (``fingerprint``).
"""

from __future__ import annotations

import base64
import io
import pickle
import zlib
from importlib import metadata
from pathlib import Path

import frictionwatch.core
from frictionwatch.core.numba_cache import source_digest

ALLOWED_NUMPY = {("numpy", "dtype"), ("numpy._core.numeric", "_frombuffer"), ("numpy.core.numeric", "_frombuffer"),
                 ("numpy._core.multiarray", "_reconstruct"), ("numpy.core.multiarray", "_reconstruct"),
                 ("numpy", "ndarray")}
ALLOWED_BUILTINS = {"set", "frozenset", "complex", "slice"}


class SnapshotError(ValueError):
    """A stored monitor state that cannot be taken back, said in one line."""


def fingerprint() -> str:
    """sha256 of frictionwatch's version and every source file of core/ (any change there: a new fingerprint)."""
    try:
        version = metadata.version("frictionwatch").encode()
    except metadata.PackageNotFoundError:
        version = b"unknown"
    return source_digest(Path(frictionwatch.core.__file__).parents[1], ("core",), salt=version)


def dumps(carried: dict) -> str:
    return encode(pickled(carried))


def pickled(carried: dict) -> bytes:
    """The carried state's bytes (the fast part: what a checkpoint of a running monitor takes under its lock)."""
    return pickle.dumps(carried, protocol=5)


def encode(raw: bytes) -> str:
    """``pickled`` bytes as the stored text (compressed, base64)."""
    return base64.b64encode(zlib.compress(raw, 6)).decode("ascii")


class _CoreOnly(pickle.Unpickler):
    def find_class(self, module: str, name: str):
        if (module, name) in ALLOWED_NUMPY or (module == "builtins" and name in ALLOWED_BUILTINS):
            return super().find_class(module, name)
        if module.startswith("frictionwatch.core.") and not name.startswith("_"):
            found = super().find_class(module, name)
            if isinstance(found, type):
                return found
        raise SnapshotError(f"a stored monitor state names {module}.{name}: not a state class of core/, not loaded")


def loads(text: str) -> dict:
    try:
        raw = zlib.decompress(base64.b64decode(text.encode("ascii"), validate=True))
        carried = _CoreOnly(io.BytesIO(raw)).load()
    except SnapshotError:
        raise
    except Exception as exc:  # noqa: BLE001 - corrupt text, truncated data, a class that changed: one line
        raise SnapshotError(f"a stored monitor state does not load: {type(exc).__name__}: {exc}"[:300]) from None
    if not isinstance(carried, dict) or not {"reference", "state", "stages", "stage_cycle", "config"} <= set(carried):
        raise SnapshotError("a stored monitor state is not what CyclePipeline.carried gives")
    return carried
