"""bench/bench_swap_against.py's swap: the named functions taken from another checkout's file of their module (here
a copy of this checkout's with one function changed), set in place by ``_use`` and put back, a module global and a
class attribute alike; a name that is not there is refused."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from frictionwatch.core.monitor.calibration import tdc_watch
from frictionwatch.core.monitor.checks import ring_pressure

from bench.bench_swap_against import _use, swaps

ROOT = Path(__file__).resolve().parents[1]


def test_swapped_functions_come_from_the_other_checkout_and_go_back(tmp_path):
    for rel in ("core/monitor/checks/ring_pressure.py", "core/monitor/calibration/tdc_watch.py"):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(ROOT / rel, tmp_path / rel)
    tw = tmp_path / "core/monitor/calibration/tdc_watch.py"
    tw.write_text(tw.read_text().replace("return self.n == n and", "return 'base' if self.n == n else"))
    this_kernel, this_fits = ring_pressure.moved_kernel, tdc_watch.TraceCut.fits
    table = swaps(tmp_path, ["frictionwatch.core.monitor.checks.ring_pressure:moved_kernel",
                             "frictionwatch.core.monitor.calibration.tdc_watch:TraceCut.fits"])
    cut = tdc_watch.trace_cut(8, [0.0])
    try:
        _use(table, True)
        assert ring_pressure.moved_kernel is not this_kernel
        assert ring_pressure.moved_kernel.py_func.__module__ != this_kernel.py_func.__module__
        assert cut.fits(8, [0.0]) == "base"
    finally:
        _use(table, False)
    assert ring_pressure.moved_kernel is this_kernel and tdc_watch.TraceCut.fits is this_fits
    assert cut.fits(8, [0.0]) is True


def test_a_module_the_other_checkout_lacks_is_refused(tmp_path):
    with pytest.raises(SystemExit, match="no core/monitor/checks/ring_pressure.py"):
        swaps(tmp_path, ["frictionwatch.core.monitor.checks.ring_pressure:moved_kernel"])
    with pytest.raises(SystemExit, match="module:attribute"):
        swaps(tmp_path, ["frictionwatch.core.monitor.checks.ring_pressure"])


def test_a_name_imported_by_value_is_swapped_where_it_is_read(tmp_path):
    """``reader:f=defining_module``: the reader's global ``f`` set to the base's ``f`` of the defining module's file
    (core.monitor.monitor reads transient_balance, imported from mean_balance by value); the defining module
    itself is not touched."""
    from frictionwatch.core.monitor import monitor
    from frictionwatch.core.monitor.balance import mean_balance

    rel = "core/monitor/balance/mean_balance.py"
    (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
    shutil.copy(ROOT / rel, tmp_path / rel)
    this = monitor.transient_balance
    table = swaps(tmp_path, ["frictionwatch.core.monitor.monitor:transient_balance="
                             "frictionwatch.core.monitor.balance.mean_balance"])
    try:
        _use(table, True)
        assert monitor.transient_balance is not this
        assert monitor.transient_balance.__module__ != this.__module__
        assert monitor.transient_balance.__code__.co_filename == str(tmp_path / rel)
        assert mean_balance.transient_balance is this
    finally:
        _use(table, False)
    assert monitor.transient_balance is this
