"""Cheaper constructors for frozen dataclasses built once per cycle (core.monitor.monitor, core.monitor.estimate, core.monitor.cycle_report).

A frozen dataclass's ``__init__`` sets each field through ``object.__setattr__`` (about 0.1 us a field); the
constructor made here fills the instance's ``__dict__`` in one step. Same class, same fields, same values: the
object is indistinguishable from ``cls(**fields)`` (equality, repr, pickling). Every field is a required keyword
argument (no defaults), so a field forgotten by a caller is a TypeError, not a missing attribute; the classes must
have no ``__post_init__`` and no ``__slots__``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable


def fast_constructor(cls: type) -> Callable:
    """``make(**fields) -> cls`` equal to ``cls(**fields)`` for a frozen dataclass without __post_init__/__slots__."""
    if not dataclasses.is_dataclass(cls) or hasattr(cls, "__post_init__") or hasattr(cls, "__slots__"):
        raise TypeError(f"{cls.__name__}: need a dataclass without __post_init__ and __slots__")
    names = [f.name for f in dataclasses.fields(cls) if f.init]
    if len(names) != len(dataclasses.fields(cls)):
        raise TypeError(f"{cls.__name__}: every field must be an __init__ field")
    args = ", ".join(names)
    body = ", ".join(f"{n!r}: {n}" for n in names)
    src = (f"def make(*, {args}):\n"
           f"    obj = _new(_cls)\n"
           f"    obj.__dict__.update({{{body}}})\n"
           f"    return obj\n")
    ns = {"_new": object.__new__, "_cls": cls}
    exec(src, ns)  # noqa: S102 - generated from the dataclass's own field names, as dataclasses does
    make = ns["make"]
    make.__doc__ = f"{cls.__name__}(**fields) without the per-field frozen __setattr__ (core.monitor.frozen_init)."
    return make
