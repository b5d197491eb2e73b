"""The ZeroMQ link to stretch_ai's bridge: two SUB sockets, one PUB socket, one receiver thread.

A background thread reads both SUB sockets (high-water mark 1, conflate: only the latest
message matters) with a short poll timeout, unpickles each message with the allow-list
unpickler, parses it and keeps the latest state and observation with their local
receive times. Reading continuously is what makes "more than 1 s without a state
message" measurable: with conflate, a reader that only looks when it needs a message
cannot tell a quiet robot from a busy reader.

Nothing here blocks without a timeout: the thread polls every 50 ms, ``wait`` takes a
timeout, sends never block (a PUB socket drops rather than waits), and ``close`` uses
linger 0 and a bounded join.
"""

from __future__ import annotations

import collections
import dataclasses
import logging
import pickle
import threading
import time
from collections.abc import Callable
from typing import Any

import zmq

from robot.config import StretchConfig
from robot.protocol import ProtocolError, RawObservation, RobotState, parse_observation, parse_state
from robot.safe_pickle import UnsafePickleError, safe_loads

log = logging.getLogger(__name__)

_POLL_MS = 50
# The bridge runs Python 3.10, whose pickle understands protocols up to 5; 4 is its default.
PICKLE_PROTOCOL = 4


def _sub_socket(ctx: zmq.Context, endpoint: str, config: StretchConfig) -> zmq.Socket:
    sock = ctx.socket(zmq.SUB)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.RCVHWM, 1)
    sock.setsockopt(zmq.CONFLATE, 1)  # keep only the latest message
    sock.setsockopt(zmq.MAXMSGSIZE, config.max_message_bytes)
    if ":" in config.host:
        sock.setsockopt(zmq.IPV6, 1)
    sock.setsockopt(zmq.SUBSCRIBE, b"")
    sock.connect(endpoint)
    return sock


class BridgeLink:
    """Latest state and observation from the robot, and a way to send actions.

    Thread-safe: the receiver thread owns the SUB sockets; ``send`` is serialised by a lock.
    """

    def __init__(self, config: StretchConfig) -> None:
        self.config = config
        self._ctx = zmq.Context()
        self._pub = self._ctx.socket(zmq.PUB)
        self._pub.setsockopt(zmq.LINGER, 0)
        self._pub.setsockopt(zmq.SNDHWM, 1)
        if ":" in config.host:
            self._pub.setsockopt(zmq.IPV6, 1)
        try:
            self._pub.connect(config.endpoint(config.action_port))
        except zmq.ZMQError as exc:
            self._pub.close(linger=0)
            self._ctx.term()
            raise RuntimeError(f"cannot connect to the robot at {config.host!r}: {exc}") from exc
        self._send_lock = threading.Lock()
        self._cond = threading.Condition()
        self._state: RobotState | None = None
        self._obs: RawObservation | None = None
        self._max_step = -(2**62)  # no echo seen yet
        self._obs_seq = 0
        # (step, seq): the first observation (by seq) whose echo reached that step; appended
        # whenever the observations' echoed step rises, so it is sorted by both.
        self._obs_echo_marks: collections.deque[tuple[int, int]] = collections.deque(maxlen=256)
        # (step, seq): the same for the first observation that echoed the step and reported
        # the base's motion over (at_goal, or last_motion_failed); both are read at send time.
        self._obs_arrival_marks: collections.deque[tuple[int, int]] = collections.deque(maxlen=256)
        self._counts = {"state": 0, "obs": 0, "refused": 0, "malformed": 0}
        self._runstopped_states = 0  # state messages that said the robot was runstopped
        self._last_problem: str | None = None
        self._stop = threading.Event()
        self._thread_error: str | None = None
        self._ready = threading.Event()
        self._thread = threading.Thread(target=self._spin, name="stretch-link", daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout=5.0) or self._thread_error:
            error = self._thread_error or "stretch link receiver did not start"
            self.close()
            raise RuntimeError(error)

    # --- receiver thread ---------------------------------------------------------------

    def _spin(self) -> None:
        cfg = self.config
        socks: list[zmq.Socket] = []
        try:
            for port in (cfg.obs_port, cfg.state_port):
                socks.append(_sub_socket(self._ctx, cfg.endpoint(port), cfg))
        except zmq.ZMQError as exc:
            for sock in socks:
                sock.close(linger=0)
            self._thread_error = f"cannot connect to the robot at {cfg.host}: {exc}"
            self._ready.set()
            return
        obs_sock, state_sock = socks
        self._ready.set()
        poller = zmq.Poller()
        poller.register(obs_sock, zmq.POLLIN)
        poller.register(state_sock, zmq.POLLIN)
        try:
            while not self._stop.is_set():
                events = dict(poller.poll(_POLL_MS))
                if state_sock in events:
                    self._receive(state_sock, "state")
                if obs_sock in events:
                    self._receive(obs_sock, "obs")
        except zmq.ZMQError as exc:
            if not self._stop.is_set():
                self._thread_error = f"robot link failed: {exc}"
                log.error("%s", self._thread_error)
        except Exception as exc:  # a bug here must end the run with a reason, not a silent thread
            self._thread_error = f"robot link receiver crashed: {type(exc).__name__}: {exc}"
            log.exception("robot link receiver crashed")
        finally:
            obs_sock.close(linger=0)
            state_sock.close(linger=0)

    def _receive(self, sock: zmq.Socket, kind: str) -> None:
        try:
            data = sock.recv(flags=zmq.NOBLOCK, copy=True)
        except zmq.Again:
            return
        now = time.monotonic()
        try:
            msg = safe_loads(data)
            parsed: RobotState | RawObservation = (
                parse_state(msg, now) if kind == "state" else parse_observation(msg, now)
            )
        except UnsafePickleError as exc:
            self._note_problem("refused", f"{kind} message refused: {exc}")
            return
        except ProtocolError as exc:
            self._note_problem("malformed", f"{kind} message not usable: {exc}")
            return
        with self._cond:
            if isinstance(parsed, RobotState):
                self._state = parsed
                if parsed.is_runstopped:
                    self._runstopped_states += 1
            else:
                self._obs_seq += 1
                parsed = dataclasses.replace(parsed, seq=self._obs_seq)
                self._obs = parsed
                marks = self._obs_echo_marks
                if parsed.step is not None and (not marks or parsed.step > marks[-1][0]):
                    marks.append((parsed.step, parsed.seq))
                arrived = self._obs_arrival_marks
                if (
                    parsed.step is not None
                    and (parsed.at_goal or parsed.last_motion_failed)
                    and (not arrived or parsed.step > arrived[-1][0])
                ):
                    arrived.append((parsed.step, parsed.seq))
            if parsed.step is not None:
                self._max_step = max(self._max_step, parsed.step)
            self._counts[kind] += 1
            self._cond.notify_all()

    def _note_problem(self, counter: str, text: str) -> None:
        with self._cond:
            self._counts[counter] += 1
            first = self._last_problem != text
            self._last_problem = text
        # Log each new kind of problem once, then every 100th repeat (a bad sender floods).
        if first or self._counts[counter] % 100 == 0:
            log.error("%s (%d so far)", text, self._counts[counter])

    # --- readers -----------------------------------------------------------------------

    @property
    def state(self) -> RobotState | None:
        with self._cond:
            return self._state

    @property
    def observation(self) -> RawObservation | None:
        with self._cond:
            return self._obs

    @property
    def echoed_step(self) -> int | None:
        """Highest step the robot has echoed in any message, None before any echo."""
        with self._cond:
            return None if self._max_step < -(2**61) else self._max_step

    def first_observation_echoing(self, step: int) -> int | None:
        """``seq`` of the first observation received that echoed ``step`` or a later one;
        None while none has. (When old marks have been dropped this may name a later
        observation than the first: never an earlier one.)"""
        return self._first_mark(self._obs_echo_marks, step)

    def first_observation_arrived(self, step: int) -> int | None:
        """``seq`` of the first observation received that echoed ``step`` or a later one and
        reported the base's motion over (``at_goal`` or ``last_motion_failed``); None while none
        has. The flags are read when the message is sent, like the step, so the observation
        after this one was grabbed after the robot said so."""
        return self._first_mark(self._obs_arrival_marks, step)

    def _first_mark(self, marks: collections.deque[tuple[int, int]], step: int) -> int | None:
        with self._cond:
            for echoed, seq in marks:
                if echoed >= step:
                    return seq
            return None

    @property
    def runstopped_states(self) -> int:
        """State messages received so far that said the robot was runstopped. Every state message
        is read as it comes (~30 Hz), so a runstop pressed and released between two of the
        backend's own checks is counted too."""
        with self._cond:
            return self._runstopped_states

    @property
    def counts(self) -> dict[str, int]:
        with self._cond:
            return dict(self._counts)

    @property
    def last_problem(self) -> str | None:
        with self._cond:
            return self._last_problem

    @property
    def failure(self) -> str | None:
        """Why the receiver thread stopped, if it did."""
        return self._thread_error

    def wait(self, predicate: Callable[[], bool], timeout_s: float) -> bool:
        """Wait until ``predicate()`` (evaluated under the link's lock after each message)
        holds or ``timeout_s`` passes. Returns the predicate's last value."""
        with self._cond:
            return self._cond.wait_for(predicate, timeout=max(0.0, timeout_s))

    # --- sending -----------------------------------------------------------------------

    def send(self, message: dict[str, Any]) -> None:
        data = pickle.dumps(message, protocol=PICKLE_PROTOCOL)
        with self._send_lock:
            if self._stop.is_set():
                log.warning("action %s not sent: the link is closed", message.get("step"))
                return
            try:
                self._pub.send(data, flags=zmq.NOBLOCK)
            except zmq.Again:
                # PUB never blocks on HWM (it drops); Again would mean no peer buffer at all.
                log.warning("action %s dropped by the PUB socket (no connection yet?)", message.get("step"))

    # --- shutdown ----------------------------------------------------------------------

    def close(self) -> None:
        if self._stop.is_set():
            return
        self._stop.set()
        self._thread.join(timeout=2.0)
        with self._send_lock:
            self._pub.close(linger=0)
        if self._thread.is_alive():
            # term() would wait for the thread's sockets forever; leave the context to the GC.
            log.error("stretch link receiver did not stop within 2 s; not terminating its context")
            return
        self._ctx.term()
