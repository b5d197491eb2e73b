"""The viewer's publishing thread: publishing never blocks the control loop.

The run's worker thread only ``offer``s its latest ``StepRecord``; this thread takes the newest
one at most ``pose_hz`` times a second (pose, images) and asks for the map at most ``map_hz``.
Records in between are skipped, which is the point.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from console.session import StepRecord

logger = logging.getLogger(__name__)


class Throttle:
    """Holds the newest offered record and publishes it on its own thread, throttled.

    ``publish(rec, with_map)`` draws a step; whoever publishes (this thread or a direct call)
    ``stamp``s the time first, so the next throttled publish waits out the period from it."""

    def __init__(self, publish: Callable[[StepRecord, bool], None], pose_hz: float, map_hz: float) -> None:
        self._publish = publish
        self._pose_period_s = 1.0 / pose_hz
        self._map_period_s = 1.0 / map_hz
        self._wake = threading.Condition(threading.Lock())
        self._latest: StepRecord | None = None
        self._closed = False
        self.last_pose_s = 0.0  # time.monotonic() of the last publish
        self.last_map_s = 0.0  # ... of the last publish with the map
        self._thread = threading.Thread(target=self._loop, name="viewer", daemon=True)
        self._thread.start()

    def stamp(self, with_map: bool) -> None:
        now = time.monotonic()
        self.last_pose_s = now
        if with_map:
            self.last_map_s = now

    def offer(self, rec: StepRecord) -> None:
        """Cheap, never blocks on publishing: the record replaces any pending one."""
        with self._wake:
            self._latest = rec
            self._wake.notify()

    def take(self) -> StepRecord | None:
        """The pending record, if any, which the thread then does not publish."""
        with self._wake:
            rec, self._latest = self._latest, None
        return rec

    def close(self, timeout_s: float = 5.0) -> None:
        with self._wake:
            self._closed = True
            self._wake.notify()
        self._thread.join(timeout_s)

    def _loop(self) -> None:
        while True:
            with self._wake:
                while self._latest is None and not self._closed:
                    self._wake.wait()
                if self._closed:
                    return
                # Throttle: wait out the pose period. An offer notifies the condition, so the wait
                # repeats until the deadline; newer records replace the pending one meanwhile.
                while True:
                    wait_s = self.last_pose_s + self._pose_period_s - time.monotonic()
                    if wait_s <= 0 or self._closed:
                        break
                    self._wake.wait(wait_s)
                if self._closed:
                    return
                rec, self._latest = self._latest, None
                if rec is None:  # taken meanwhile (a run started or ended)
                    continue
            with_map = time.monotonic() - self.last_map_s >= self._map_period_s
            try:
                self._publish(rec, with_map)
            except Exception:  # the viewer must never take the console down; log and go on
                logger.exception("viewer publishing failed at step %d", rec.step)
