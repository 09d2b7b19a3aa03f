"""A live session's ingest thread (service/live.py ``LiveSession``): the queued batches merged into time order
(service/record_merge.py), written to the black-box recorder, fed to the engine pipeline; each result to
``on_result`` under the session's lock, then ``after_results`` with it released. ``IngestThread`` is a mixin of
LiveSession: its attributes are the session's.
"""

from __future__ import annotations

import logging
import queue
import time

from frictionwatch.core.monitor.report.results import CycleResult
from frictionwatch.drivers.source import StreamRestart
from frictionwatch.service.ingest_queue import Dropped
from frictionwatch.service.live_readers import END
from frictionwatch.service.record_merge import Keyed
from frictionwatch.service.stream_holes import hole_mark

log = logging.getLogger("frictionwatch.service.live")  # the session's own logger, as before the split

# results after which the monitor is warm: past the TDC watch's first window (100 cycles) and its first fit, whose
# kernels compile then (a cold `make run` dropped 2.6 s of the demo just after its first result with 1 here)
WARM_RESULTS = 150


class IngestThread:
    """LiveSession's ingest thread (see the module docstring)."""

    def _ingest_loop(self) -> None:
        if self.before_ingest is not None:
            try:
                self.before_ingest()
            except Exception as exc:  # noqa: BLE001 - a consumer's bug must not stop the monitor
                self._error("before_ingest", exc)
        while True:
            try:
                name, item = self._queue.get(timeout=min(0.05, self.quiet_s / 2))
            except queue.Empty:
                name, item = "", None
            if name is None:  # stop(): the readers have ended; what is still queued came before this
                break
            if time.monotonic() > self._drain_until and self.left_at_stop is None:
                self._left_at_stop()
            now = time.monotonic()
            quiet = {n for n, t in self._heard.items() if now - t >= self.quiet_s}
            with self._cond:  # the merge's progress and counts are read by other threads
                released = []
                if quiet != self.merge.quiet:
                    released = self.merge.set_quiet(quiet)
                if name:
                    released += (self.merge.end(name) if item is END else
                                 self.merge.push(name, *hole_mark(item, self.info)) if isinstance(item, Dropped) else
                                 self.merge.push(name, item.records, item.keys))
                self._cond.notify_all()
            self._deliver(released)
        with self._cond:
            released = self.merge.flush()
        self._deliver(released)
        with self._cond:
            # sources that ended (a finite log) end the stream: its last partial cycle is counted; a stop cuts it
            ended = len(self.merge.ended) == len(self.sources)
            outcomes = self.pipeline.outcomes(None) if ended else self.pipeline.cut_off()
            self._publish([o.result for o in outcomes if o.result is not None])
            self._cond.notify_all()
        self._hand_on()

    def _left_at_stop(self) -> None:
        """The drain's time is up: drop what is queued, say how much."""
        records, span_s = self._queue.discard()
        self.left_at_stop = (records, span_s)
        if records:
            log.warning("live session: stop left %d queued records (%.1f s of acquisition) unanalysed: the drain's "
                        "%.1f s were up", records, span_s, self.drain_s)

    def _deliver(self, keyed: Keyed) -> None:
        if not keyed:
            return
        records = [r for _, r in keyed]
        data = [r for r in records if not isinstance(r, StreamRestart)]  # a restart mark: not data (below)
        if self.recorder is not None:
            with self._recording:
                if self._recorder_closed:  # delivered after stop closed the recorder (its drain ran out)
                    self.errors["not_recorded_after_stop"] += len(records)
                else:
                    for r in records:  # the marks too: a recording says where the stream restarted, what a hole lost
                        try:
                            self.recorder.write(r)
                        except OSError as exc:  # disk full, folder gone: the black box fails, the monitor goes on
                            self._error("recorder", exc)
        if self.on_records is not None and data:
            keys = ([k for k, r in keyed if not isinstance(r, StreamRestart)] if len(data) < len(records) else
                    [k for k, _ in keyed])
            try:
                self.on_records(data, keys)
            except Exception as exc:  # noqa: BLE001 - a consumer's bug must not stop the monitor
                self._error("on_records", exc)
        for r in records:
            if isinstance(r, StreamRestart):  # recorded (above), not handed on: the pipeline restarts
                with self._cond:
                    self._publish(self.pipeline.feed(r))
                self._hand_on()
                continue
            with self._cond:
                self.records_fed += 1
                try:
                    results = self.pipeline.feed(r)
                except Exception as exc:  # noqa: BLE001 - a bug met by odd input: counted, logged, stream goes on
                    self._error("pipeline", exc)
                    continue
                if results:
                    self._publish(results)
            self._hand_on()  # out of the lock: it may wait for a listener (backpressure), the monitor free meanwhile
        with self._cond:
            self._cond.notify_all()

    def _publish(self, results: list[CycleResult]) -> None:
        """Called with ``_cond`` held."""
        self._results_seen += len(results)
        if self._results_seen >= WARM_RESULTS and not self._warm.is_set():
            self._warm.set()
            for name in self._paced_replays:  # their clocks start again from where they waited
                getattr(self.sources[name], "inner", self.sources[name]).reanchor()
        for res in results:
            self._history.append(res)
            if self.on_result is not None:
                try:
                    self.on_result(res)
                except Exception as exc:  # noqa: BLE001 - a consumer's bug must not stop the monitor
                    self._error("on_result", exc)
        if results:
            self._unsent = True
            self._cond.notify_all()

    def _hand_on(self) -> None:
        """``after_results`` for what ``_publish`` gave ``on_result`` (called with the lock released)."""
        if self._unsent:
            self._unsent = False
            if self.after_results is not None:
                try:
                    self.after_results()
                except Exception as exc:  # noqa: BLE001 - a consumer's bug must not stop the monitor
                    self._error("after_results", exc)

    def _error(self, where: str, exc: BaseException) -> None:
        reason = f"{where}: {type(exc).__name__}"
        if self.errors[reason] == 0:
            log.error("live session: %s failed: %s", where, exc, exc_info=exc)
        self.errors[reason] += 1
