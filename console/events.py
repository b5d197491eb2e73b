"""Fan-out of run status events from the worker thread to live-stream clients.

The runner publishes from its own thread; each server-sent-events client holds
an ``asyncio.Queue`` on the server's event loop. ``publish`` never blocks: it
hands the event to each subscriber's loop with ``call_soon_threadsafe``, and a
subscriber that falls behind loses its oldest events (a status stream only needs
the latest state; the full record is in SQLite).
"""

from __future__ import annotations

import asyncio
import itertools
import json
import logging
import threading
from collections.abc import AsyncIterator, Mapping
from dataclasses import dataclass, field
from typing import Any

logger = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class Event:
    """One status event. ``kind``: ``status`` (a run changed state), ``step`` (a step
    was taken), ``log`` (console preparation progress). ``run_id`` is None for
    console-wide events."""

    seq: int
    kind: str
    run_id: str | None
    data: Mapping[str, Any] = field(default_factory=dict)

    def to_sse(self) -> str:
        payload = json.dumps({"seq": self.seq, "kind": self.kind, "run_id": self.run_id, **self.data})
        return f"id: {self.seq}\nevent: {self.kind}\ndata: {payload}\n\n"


class _Subscriber:
    __slots__ = ("loop", "queue", "run_id")

    def __init__(self, loop: asyncio.AbstractEventLoop, run_id: str | None, maxsize: int) -> None:
        self.loop = loop
        self.queue: asyncio.Queue[Event | None] = asyncio.Queue(maxsize=maxsize)
        self.run_id = run_id

    def offer(self, event: Event | None) -> None:
        """Runs on the subscriber's loop."""
        if self.queue.full():
            try:
                self.queue.get_nowait()  # drop the oldest: the newest state matters
            except asyncio.QueueEmpty:  # pragma: no cover - raced with the reader
                pass
        self.queue.put_nowait(event)


class EventHub:
    """Thread-safe publish, asyncio subscribe."""

    def __init__(self, queue_size: int = 256) -> None:
        self._lock = threading.Lock()
        self._subscribers: set[_Subscriber] = set()
        self._seq = itertools.count(1)
        self._queue_size = queue_size
        self._closed = False
        self._last_by_run: dict[str | None, Event] = {}

    @property
    def n_subscribers(self) -> int:
        with self._lock:
            return len(self._subscribers)

    def publish(self, kind: str, run_id: str | None, data: Mapping[str, Any]) -> Event:
        event = Event(next(self._seq), kind, run_id, dict(data))
        with self._lock:
            if kind in ("status", "step"):
                self._last_by_run[run_id] = event
            subscribers = list(self._subscribers)
        for sub in subscribers:
            if sub.run_id is not None and sub.run_id != run_id:
                continue
            try:
                sub.loop.call_soon_threadsafe(sub.offer, event)
            except RuntimeError:  # the subscriber's loop is closed; it will unsubscribe itself
                logger.debug("dropping event for a subscriber whose loop closed")
        return event

    def last_event(self, run_id: str) -> Event | None:
        with self._lock:
            return self._last_by_run.get(run_id)

    async def subscribe(self, run_id: str | None = None, heartbeat_s: float = 15.0) -> AsyncIterator[str]:
        """Yield SSE-formatted text: the run's latest event first, then live events.

        A comment line every ``heartbeat_s`` keeps proxies from closing an idle stream."""
        sub = _Subscriber(asyncio.get_running_loop(), run_id, self._queue_size)
        with self._lock:
            if self._closed:
                return
            self._subscribers.add(sub)
            last = self._last_by_run.get(run_id) if run_id is not None else None
        try:
            yield "retry: 2000\n\n"
            if last is not None:
                yield last.to_sse()
            while True:
                try:
                    event = await asyncio.wait_for(sub.queue.get(), timeout=heartbeat_s)
                except TimeoutError:
                    yield ": keep-alive\n\n"
                    continue
                if event is None:  # hub closed
                    return
                yield event.to_sse()
        finally:
            with self._lock:
                self._subscribers.discard(sub)

    def close(self) -> None:
        """End every stream (server shutdown)."""
        with self._lock:
            self._closed = True
            subscribers = list(self._subscribers)
        for sub in subscribers:
            try:
                sub.loop.call_soon_threadsafe(sub.offer, None)
            except RuntimeError:
                pass
