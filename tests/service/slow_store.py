"""A store slower than a replay, for the backpressure tests (tests/service/test_replay_backpressure.py) and bench
(bench/bench_replay_store.py): the demo log played several times over and then ended (not real time), and an engine
whose store (the real one, joined by DataDir as serve joins it) commits each cycle alone, each commit slowed."""

from __future__ import annotations

import functools
import time

from frictionwatch.drivers.errors import EndOfStream
from frictionwatch.drivers.logs.mcap_replay import McapSource
from frictionwatch.drivers.source import Source, StreamRestart
from frictionwatch.service.data_dir import DataDir
from frictionwatch.service.engine_service import EngineService
from frictionwatch.service.pipeline import resolve_model
from frictionwatch.service.store import StoreListener

from tests.service.serve_helpers import DEMO

ENGINE = "genset-v20"


class DemoPasses(Source):
    """The demo log read as fast as it can be, ``passes`` times over, then its end: a longer log than the demo's
    ~40 cycles, not real time (no ``speed``)."""

    def __init__(self, passes: int) -> None:
        super().__init__()
        self._log = McapSource(DEMO, loop=True)
        self.info, self.engine_toml, self.damage = self._log.info, self._log.engine_toml, self._log.damage
        self.passes, self._seams = passes, 0

    def _read_internal(self, timeout: float | None) -> list:
        if self._seams >= self.passes:
            raise EndOfStream("the last pass ended")
        records = self._log.read(timeout)
        for i, r in enumerate(records):
            if isinstance(r, StreamRestart):
                self._seams += 1
                if self._seams >= self.passes:
                    return records[:i]
        return records

    def _close_internal(self) -> None:
        self._log.close()


def slow_store_engine(where, source: Source, write_s: float, **options) -> tuple[DataDir, EngineService]:
    """An engine on ``source`` (EngineService ``options``) with a store at ``where`` (DataDir's) whose every cycle
    is a commit of its own slowed by ``write_s``."""
    data = DataDir(where)
    write = data.store.write_batch

    def slow_write(*args, **kwargs):
        time.sleep(write_s)
        return write(*args, **kwargs)

    data.store.write_batch = slow_write
    data._listener = functools.partial(StoreListener, batch_cycles=1)  # a commit a cycle
    model = resolve_model(source.engine_toml, None, "demo", source.info)
    svc = EngineService(ENGINE, model, source.info, {"log": source}, **options)
    data.attach(svc)
    return data, svc


def stored(data: DataDir) -> list[int]:
    """The cycle indices the store holds, in order."""
    return [int(r["cycle_index"]) for r in data.store.cycles(ENGINE, 0, 10**9)]
