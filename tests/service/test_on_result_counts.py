"""What the ingest thread copies for the API after each result (EngineService._on_result: the skip and restart
counts, the TDC watch's view, the term names) is copied only where it changed (design note 92); at every cycle it
must still equal what the pipeline holds then. A looped demo log with tooth batches dropped in its second pass (the
assembler skips cycles there) and a seam at each pass (restarts): checked on the ingest thread itself, after each
result, under the session's lock."""

from __future__ import annotations

from frictionwatch.core.types import ToothBatch
from frictionwatch.drivers.source import Source, open_source
from frictionwatch.drivers.timebase import Clocks
from frictionwatch.service.engine_service import EngineService
from frictionwatch.service.pipeline import resolve_model

from tests.service.serve_helpers import DEMO, wait_until

DROPPED = range(60, 64)  # tooth batches read in the second pass that are dropped (a gap: cycles skipped)


class DroppingSource(Source):
    """The looped demo with some tooth batches of its second pass left out."""

    def __init__(self, inner: Source) -> None:
        super().__init__()
        self.inner, self.damage, self.info, self.engine_toml = inner, inner.damage, inner.info, inner.engine_toml
        self.teeth = 0

    def _read_internal(self, timeout: float | None) -> list:
        out = []
        for r in self.inner.read(timeout):
            if isinstance(r, ToothBatch) and self.inner.passes == 1:
                self.teeth += 1
                if self.teeth in DROPPED:
                    continue
            out.append(r)
        return out

    def _close_internal(self) -> None:
        self.inner.close()


class CheckedService(EngineService):
    """Compares, after each result, what _on_result copied with what the pipeline holds."""

    def __init__(self, *a, **k) -> None:
        super().__init__(*a, **k)
        self.checked, self.differences, self.skips_seen = 0, [], 0

    def _on_result(self, result) -> None:
        super()._on_result(result)
        pipe = self.session.pipeline
        now = {"skipped": dict(pipe.skipped), "restarts": dict(pipe.restarts), "terms": self._monitor_terms(),
               "tdc_window_cycle": pipe.tdc_window_cycle}
        kept = {"skipped": self.skipped, "restarts": self.restarts, "terms": self.term_names,
                "tdc_window_cycle": self.tdc_watch.window_cycle}
        if now != kept or self.tdc_watch.state is not pipe.tdc_watch:
            self.differences.append((int(result.index), kept, now))
        self.checked += 1
        self.skips_seen = max(self.skips_seen, sum(self.skipped.values()))


def test_the_copied_counts_equal_the_pipeline_s_after_every_result():
    url = f"mcap:{DEMO}?loop=1"
    src = open_source(url, Clocks())
    model = resolve_model(src.engine_toml, None, "demo", src.info)
    wrapped = DroppingSource(src)
    svc = CheckedService("demo", model, src.info, {"log": wrapped}, urls=[url])
    svc.start()
    try:
        assert wait_until(lambda: src.passes >= 3, timeout=240.0)
    finally:
        svc.stop()
    assert svc.checked > 100
    assert svc.differences == []
    assert svc.skips_seen > 0  # the dropped teeth cost cycles: the skip counts did change during the run
    assert svc.restarts.get("loop_restart", 0) >= 2
