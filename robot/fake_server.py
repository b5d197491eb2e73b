"""A fake Stretch that speaks stretch_ai's ZeroMQ bridge protocol (docs/architecture.md section 6).

It binds the bridge's three ports, publishes pickled observation dicts (~10 Hz, JPEG RGB
and JPEG2000 millimetre depth of the portrait head camera, ``camera_K``,
``camera_pose``, ``gps``/``compass``, ``rgb_width``/``rgb_height`` with the robot's
swapped meanings) and state dicts (~30 Hz), and handles actions the way the bridge does:

* an action whose ``step`` is not greater than the last handled one (or that has none)
  is dropped;
* ``xyt`` goals move the base along the straight segment to the goal and stop where
  the robot would collide (``last_motion_failed`` then says so); the receive loop is
  blocked for the whole motion and the step is echoed only afterwards;
* an ``xyt`` without ``nav_relative`` kills the receive loop (the bridge raises a
  KeyError in its receive thread and never acknowledges again);
* ``posture`` blocks while the arm tucks and points the head down; ``head_to`` is not
  blocking: echoed at once, the head then moves;
* a runstop freezes motion (the move resumes when released, like the real goto
  controller, and the echo waits for it);
* ``at_goal`` (in state and observation messages) turns false when a goal is accepted and
  true when the base has arrived; it stays false after a motion that failed.

Non-blocking navigation (``FakeKnobs.nonblocking_nav``), as stretch_ai's MuJoCo server
(``src/stretch/simulation/mujoco_server.py``) does: an ``xyt`` goal is handed to a motion
thread and the step is echoed at once, with ``at_goal`` false; the base then moves and
``at_goal`` turns true only when it has arrived. A client that trusts the echo takes
observations from mid-motion. ``never_arrive`` makes such a motion stall halfway with
``at_goal`` false for good (a goto controller that never finishes); ``reports_at_goal``
False leaves ``at_goal`` out of every message (a server that does not report it).

Observations are built in the bridge's order (``FakeKnobs.faithful``, on by default):
the camera images are grabbed (rendered) first, then the base pose and camera pose are
read, then the images are compressed, and the last handled ``step`` is read only when
the message is stamped for sending, while the base keeps moving in between. As on the
robot, an observation that echoes step N can therefore hold images from before step N's
motion ended (and a pose from after it). The loop runs back to back at the
observation rate, like the bridge's publisher (its compression sets its pace).
``faithful=False`` reads every field at one instant instead (an idealised robot).

Knobs for tests (``FakeKnobs``, changeable while running): runstop, not homed, dropped
acknowledgements, silence (publish nothing), slow moves (speeds), whether state
messages carry ``step``, faithful observation order, non-blocking navigation, a motion
that never arrives, whether messages carry ``at_goal``. Between runs a test may move the base
by hand (``push_base``) or start the robot's localisation again where the base stands
(``reset_localisation``: the reported poses are then in a new map frame, as after a SLAM
restart).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import zmq

from agent.types import Pose2D, wrap_angle
from robot import encoding
from robot.fake_world import FakeWorld
from robot.protocol import ACTION_PORT, NO_STEP, OBS_PORT, STATE_PORT
from robot.safe_pickle import UnsafePickleError, safe_loads

log = logging.getLogger(__name__)

_COLLISION_STEP_M = 0.01
_MOTION_TICK_S = 0.02
# Head tilt (down) that the navigation posture leaves, as stretch_ai's posture looks down
# at the floor in front; the client must then level it with head_to.
NAV_POSTURE_TILT_RAD = math.radians(35.0)


@dataclass
class FakeKnobs:
    """Faults and speeds of the fake robot; plain attributes, read by the server's threads."""

    runstopped: bool = False
    homed: bool = True
    drop_acks: bool = False  # handle actions but never echo their steps
    silent: bool = False  # publish nothing on either stream
    observations_paused: bool = False  # publish state but no observations (a stalled camera stream)
    linear_speed_m_s: float = 2.0  # fast by default so tests run quickly; lower = slow moves
    angular_speed_rad_s: float = 6.0
    head_speed_rad_s: float = 3.0
    posture_s: float = 0.1
    state_has_step: bool = True
    # The bridge's observation order (images, then pose, then compression, then the step
    # stamped at send time, motion continuing throughout); False: all fields at one instant.
    faithful: bool = True
    # Echo an xyt goal at once and move afterwards, at_goal false until the base arrives
    # (stretch_ai's MuJoCo server); False: block the receive loop until arrival (the bridge).
    nonblocking_nav: bool = False
    # With nonblocking_nav: the base stalls halfway and at_goal never turns true.
    never_arrive: bool = False
    reports_at_goal: bool = True  # False: no 'at_goal' key in state or observation messages


@dataclass(frozen=True, slots=True)
class _Snapshot:
    pose: Pose2D  # in the world (what the camera sees from)
    map_pose: Pose2D  # as the robot's localisation reports it, in its map frame
    tilt_rad: float
    echo_step: int
    at_goal: bool
    last_motion_failed: bool
    control_mode: str


class FakeStretch:
    """The fake robot server. ``start()`` binds and starts the threads; ``close()`` stops them.

    Ports may be 0: a free port is chosen; read the bound ports from ``ports`` after start.
    """

    def __init__(
        self,
        world: FakeWorld,
        host: str = "127.0.0.1",
        obs_port: int = OBS_PORT,
        action_port: int = ACTION_PORT,
        state_port: int = STATE_PORT,
        knobs: FakeKnobs | None = None,
        obs_hz: float = 10.0,
        state_hz: float = 30.0,
        start_step: int = NO_STEP,
    ) -> None:
        self.world = world
        self.host = host
        self.knobs = knobs or FakeKnobs()
        self._requested_ports = (obs_port, action_port, state_port)
        self.ports: tuple[int, int, int] | None = None
        self._obs_period_s = 1.0 / obs_hz
        self._state_period_s = 1.0 / state_hz
        self._lock = threading.Lock()
        self._pose = world.start_world
        self._map_world: Pose2D | None = None  # the map frame in the world; None: the world frame itself
        self._tilt_rad = math.radians(20.0)
        self._tilt_goal_rad = self._tilt_rad
        self._handled_step = start_step
        self._echo_step = start_step
        self._at_goal = True
        self._last_motion_failed = False
        self._control_mode = "navigation"
        self.actions: list[dict[str, Any]] = []  # every handled action, for tests
        self.refused_messages = 0
        self.receiver_alive = False
        self._motion_gen = 0  # bumped by every new goal; a superseded motion thread stops
        self._motion_threads: list[threading.Thread] = []
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._ctx: zmq.Context | None = None
        self._render_key: tuple | None = None
        self._render_raw_cache: tuple[np.ndarray, np.ndarray] | None = None
        self._render_cache: tuple[np.ndarray, np.ndarray] | None = None
        self._render_shape: tuple[int, int] = (0, 0)

    # --- lifecycle ---------------------------------------------------------------------

    def start(self) -> FakeStretch:
        self._ctx = zmq.Context()
        obs_sock = self._pub_socket(self._requested_ports[0])
        state_sock = self._pub_socket(self._requested_ports[2])
        act_sock = self._ctx.socket(zmq.SUB)
        act_sock.setsockopt(zmq.LINGER, 0)
        act_sock.setsockopt(zmq.RCVHWM, 1)
        act_sock.setsockopt(zmq.CONFLATE, 1)
        act_sock.setsockopt(zmq.SUBSCRIBE, b"")
        act_port = self._bind(act_sock, self._requested_ports[1])
        self.ports = (self._port_of(obs_sock), act_port, self._port_of(state_sock))
        self.receiver_alive = True
        for target, sock, name in (
            (self._spin_obs, obs_sock, "fake-stretch-obs"),
            (self._spin_state, state_sock, "fake-stretch-state"),
            (self._spin_recv, act_sock, "fake-stretch-recv"),
        ):
            thread = threading.Thread(target=target, args=(sock,), name=name, daemon=True)
            self._threads.append(thread)
            thread.start()
        log.info("fake Stretch on %s: observations %d, actions %d, state %d", self.host, *self.ports)
        return self

    def close(self) -> None:
        if self._stop.is_set():
            return
        self._stop.set()
        alive = []
        for thread in self._threads + self._motion_threads:
            thread.join(timeout=5.0)
            if thread.is_alive():
                alive.append(thread.name)
        if alive:
            log.error("fake Stretch threads did not stop: %s", alive)
        elif self._ctx is not None:
            self._ctx.term()

    def __enter__(self) -> FakeStretch:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _pub_socket(self, port: int) -> zmq.Socket:
        assert self._ctx is not None
        sock = self._ctx.socket(zmq.PUB)
        sock.setsockopt(zmq.LINGER, 0)
        sock.setsockopt(zmq.SNDHWM, 1)
        self._bind(sock, port)
        return sock

    def _bind(self, sock: zmq.Socket, port: int) -> int:
        sock.bind(f"tcp://{self.host}:{port if port else '*'}")
        return self._port_of(sock)

    @staticmethod
    def _port_of(sock: zmq.Socket) -> int:
        endpoint = sock.getsockopt_string(zmq.LAST_ENDPOINT)
        return int(endpoint.rsplit(":", 1)[1])

    # --- what tests read ---------------------------------------------------------------

    @property
    def pose_world(self) -> Pose2D:
        with self._lock:
            return self._pose

    @property
    def tilt_rad(self) -> float:
        with self._lock:
            return self._tilt_rad

    @property
    def handled_step(self) -> int:
        with self._lock:
            return self._handled_step

    @property
    def echoed_step(self) -> int:
        """The step the robot's messages echo (behind ``handled_step`` while acks are dropped)."""
        with self._lock:
            return self._echo_step

    def push_base(self, pose_world: Pose2D) -> None:
        """The base is moved by hand (pushed while runstopped, or carried): it stands at
        ``pose_world`` at once, without a command, and the localisation follows it (the
        reported pose is the new one, in the same map frame)."""
        if self.world.collides(pose_world.x_m, pose_world.y_m):
            raise ValueError(f"the base cannot stand at {pose_world}")
        with self._lock:
            self._motion_gen += 1  # a motion under way ends here
            self._pose = pose_world
            self._at_goal = True

    def reset_localisation(self) -> None:
        """The robot's localisation starts again where the base stands (stretch_ai's SLAM
        restarted, as after a power cycle): the reported pose becomes the origin of a new map
        frame; the base does not move. Absolute goals are read in the new frame from then on."""
        with self._lock:
            self._map_world = self._pose

    def _map_pose(self, pose_world: Pose2D) -> Pose2D:
        return pose_world if self._map_world is None else pose_world.relative_to(self._map_world)

    def _snapshot(self) -> _Snapshot:
        with self._lock:
            return _Snapshot(
                self._pose,
                self._map_pose(self._pose),
                self._tilt_rad,
                self._echo_step,
                self._at_goal,
                self._last_motion_failed,
                self._control_mode,
            )

    # --- publishers --------------------------------------------------------------------

    def _spin_state(self, sock: zmq.Socket) -> None:
        try:
            next_t = time.monotonic()
            while not self._stop.wait(max(0.0, next_t - time.monotonic())):
                next_t += self._state_period_s
                self._advance_head(self._state_period_s)
                if self.knobs.silent:
                    continue
                snap = self._snapshot()
                msg: dict[str, Any] = {
                    "base_pose": np.array(snap.map_pose.as_tuple()),
                    "ee_pose": np.eye(4),
                    "joint_positions": np.zeros(11),
                    "joint_velocities": np.zeros(11),
                    "joint_efforts": np.zeros(11),
                    "control_mode": snap.control_mode,
                    "at_goal": snap.at_goal,
                    "is_homed": bool(self.knobs.homed),
                    "is_runstopped": bool(self.knobs.runstopped),
                }
                if self.knobs.state_has_step:
                    msg["step"] = snap.echo_step
                if not self.knobs.reports_at_goal:
                    del msg["at_goal"]
                sock.send_pyobj(msg, protocol=4)
        finally:
            sock.close(linger=0)

    def _spin_obs(self, sock: zmq.Socket) -> None:
        try:
            next_t = time.monotonic()
            while not self._stop.wait(max(0.0, next_t - time.monotonic())):
                t_grab = time.monotonic()
                if self.knobs.silent or self.knobs.observations_paused:
                    next_t = t_grab + self._obs_period_s
                    continue
                if self.knobs.faithful:
                    # The bridge's order: grab the images, read the poses, compress, and only
                    # then read the step to stamp the message; the base moves meanwhile.
                    grab = self._snapshot()
                    key = self._render_raw(grab.pose, grab.tilt_rad)
                    read = self._snapshot()
                    rgb_enc, depth_enc, shape = self._encoded(key)
                    # The robot's compression sets the publishing pace: the next grab follows
                    # this send at once, so the period is spent between grab and send.
                    if self._stop.wait(max(0.0, t_grab + self._obs_period_s - time.monotonic())):
                        break
                    if self.knobs.silent or self.knobs.observations_paused:
                        continue  # the fault began while this one was being compressed
                    stamp = self._snapshot()
                    next_t = time.monotonic()
                else:
                    read = stamp = self._snapshot()
                    rgb_enc, depth_enc, shape = self._encoded(self._render_raw(read.pose, read.tilt_rad))
                    next_t = max(next_t + self._obs_period_s, t_grab)
                sock.send_pyobj(self._observation_message(read, stamp, rgb_enc, depth_enc, shape), protocol=4)
        finally:
            sock.close(linger=0)

    def _observation_message(
        self, read: _Snapshot, stamp: _Snapshot, rgb_enc: np.ndarray, depth_enc: np.ndarray, shape: tuple[int, int]
    ) -> dict[str, Any]:
        """``read``: poses read after the images were grabbed; ``stamp``: what the bridge reads
        when it builds the dict (step, motion flags, control mode)."""
        msg: dict[str, Any] = {
            "rgb": rgb_enc,
            "depth": depth_enc,
            "camera_K": self.world.intrinsics.K.astype(np.float32),
            "camera_pose": encoding.make_camera_pose(
                read.map_pose.x_m, read.map_pose.y_m, read.map_pose.yaw_rad, self.world.camera_height_m, read.tilt_rad
            ),
            "ee_pose": np.eye(4),
            "joint": np.zeros(11),
            "gps": np.array([read.map_pose.x_m, read.map_pose.y_m]),
            "compass": np.array([read.map_pose.yaw_rad]),
            # the bridge's swapped meanings: width, height = rgb.shape[:2]
            "rgb_width": shape[0],
            "rgb_height": shape[1],
            "control_mode": stamp.control_mode,
            "last_motion_failed": stamp.last_motion_failed,
            "recv_address": f"tcp://{self.host}:{self.ports[1] if self.ports else 0}",
            "step": stamp.echo_step,
            "at_goal": stamp.at_goal,
        }
        if not self.knobs.reports_at_goal:
            del msg["at_goal"]
        return msg

    def _render_raw(self, pose: Pose2D, tilt_rad: float) -> tuple:
        """Grab the camera images at ``pose`` (rendered once per distinct pose); returns the cache key."""
        key = (round(pose.x_m, 4), round(pose.y_m, 4), round(pose.yaw_rad, 4), round(tilt_rad, 3))
        if key != self._render_key or self._render_raw_cache is None:
            self._render_raw_cache = self.world.render(pose, tilt_rad)
            self._render_cache = None
            self._render_key = key
        return key

    def _encoded(self, key: tuple) -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
        """The grabbed images compressed like the robot's (JPEG RGB, JPEG2000 millimetres)."""
        assert key == self._render_key and self._render_raw_cache is not None
        if self._render_cache is None:
            rgb, depth_m = self._render_raw_cache
            self._render_cache = (encoding.encode_rgb(rgb), encoding.encode_depth(depth_m))
            self._render_shape = rgb.shape[:2]
        return self._render_cache[0], self._render_cache[1], self._render_shape

    def _advance_head(self, dt_s: float) -> None:
        if self.knobs.runstopped:
            return
        with self._lock:
            delta = self._tilt_goal_rad - self._tilt_rad
            limit = self.knobs.head_speed_rad_s * dt_s
            self._tilt_rad += max(-limit, min(limit, delta))

    # --- receiver ----------------------------------------------------------------------

    def _spin_recv(self, sock: zmq.Socket) -> None:
        poller = zmq.Poller()
        poller.register(sock, zmq.POLLIN)
        try:
            while not self._stop.is_set():
                if not dict(poller.poll(50)):
                    continue
                try:
                    action = safe_loads(sock.recv(flags=zmq.NOBLOCK))
                except zmq.Again:
                    continue
                except UnsafePickleError as exc:
                    self.refused_messages += 1
                    log.error("fake Stretch refused an action: %s", exc)
                    continue
                if not isinstance(action, dict):
                    log.warning("fake Stretch: ignoring a %s action", type(action).__name__)
                    continue
                step = action.get("step", NO_STEP)
                with self._lock:
                    if step <= self._handled_step:
                        log.debug("fake Stretch: skipping duplicate step %s (last %d)", step, self._handled_step)
                        continue
                try:
                    self._handle(action)
                except KeyError as exc:
                    # What the bridge's receive thread does on an xyt without nav_relative.
                    log.error("fake Stretch receive loop died on %s: missing %s", sorted(action), exc)
                    self.receiver_alive = False
                    return
                with self._lock:
                    self._handled_step = max(self._handled_step, int(step))
                    if not self.knobs.drop_acks:
                        self._echo_step = self._handled_step
                    self.actions.append(dict(action))
        finally:
            sock.close(linger=0)

    def _handle(self, action: dict[str, Any]) -> None:
        if "posture" in action:
            if action["posture"] == "navigation":
                self._wait_motion(self.knobs.posture_s)
                with self._lock:
                    self._control_mode = "navigation"
                    self._tilt_goal_rad = NAV_POSTURE_TILT_RAD
            else:
                log.warning("fake Stretch: posture %r not supported", action["posture"])
        elif "xyt" in action:
            relative = action["nav_relative"]  # KeyError on purpose, as on the robot
            xyt = [float(v) for v in action["xyt"]]
            goal = Pose2D(*xyt)
            if relative:
                goal = self.pose_world.compose(goal)
            else:
                with self._lock:  # an absolute goal is in the robot's map frame
                    if self._map_world is not None:
                        goal = self._map_world.compose(goal)
            with self._lock:
                mode = self._control_mode
            if mode != "navigation":
                log.warning("fake Stretch: xyt goal ignored in %s mode", mode)
                return
            goal = Pose2D(goal.x_m, goal.y_m, wrap_angle(goal.yaw_rad))
            with self._lock:
                # a new goal supersedes a motion still running (as a goto controller's goal)
                self._motion_gen += 1
                gen = self._motion_gen
                self._at_goal = False
                self._last_motion_failed = False
            if not self.knobs.nonblocking_nav:
                self._move_to(goal, gen)
                return
            # acknowledged as soon as this returns; the base moves on its own thread
            stall = 0.5 if self.knobs.never_arrive else None
            thread = threading.Thread(
                target=self._move_to, args=(goal, gen, stall), name=f"fake-stretch-move-{gen}", daemon=True
            )
            self._motion_threads = [t for t in self._motion_threads if t.is_alive()] + [thread]
            thread.start()
        elif "head_to" in action:
            pan, tilt = (float(v) for v in action["head_to"])
            if abs(pan) > 1e-3:
                log.warning("fake Stretch: head pan %.2f not supported (camera stays forward)", pan)
            with self._lock:
                self._tilt_goal_rad = -tilt  # the bridge's tilt is negative looking down
        else:
            log.warning("fake Stretch: action not recognized or supported: %s", sorted(action))

    def _wait_motion(self, duration_s: float) -> bool:
        """Let ``duration_s`` of motion time pass (frozen while runstopped); False if closing."""
        elapsed = 0.0
        last = time.monotonic()
        while elapsed < duration_s or self.knobs.runstopped:
            if self._stop.wait(_MOTION_TICK_S):
                return False
            now = time.monotonic()
            if not self.knobs.runstopped:
                elapsed += now - last
            last = now
        return True

    def _move_to(self, goal: Pose2D, gen: int, stall_at: float | None = None) -> None:
        """Drive to ``goal`` (motion ``gen``); with ``stall_at`` stop at that fraction of the
        way and never report arrival."""
        start = self.pose_world
        dist = start.distance_to(goal)
        dyaw = wrap_angle(goal.yaw_rad - start.yaw_rad)
        n = max(1, int(math.ceil(dist / _COLLISION_STEP_M)))
        reach = 1.0
        if dist > 0:
            for i in range(1, n + 1):
                f = i / n
                if self.world.collides(start.x_m + f * (goal.x_m - start.x_m), start.y_m + f * (goal.y_m - start.y_m)):
                    reach = (i - 1) / n
                    break
        blocked = reach < 1.0
        if stall_at is not None:
            reach, blocked = min(reach, stall_at), False

        def at(f: float) -> Pose2D:
            return Pose2D(
                start.x_m + f * (goal.x_m - start.x_m),
                start.y_m + f * (goal.y_m - start.y_m),
                wrap_angle(start.yaw_rad + f * dyaw),
            )

        duration = reach * max(dist / self.knobs.linear_speed_m_s, abs(dyaw) / self.knobs.angular_speed_rad_s)
        elapsed = 0.0
        last = time.monotonic()
        while elapsed < duration or self.knobs.runstopped:
            if self._stop.wait(_MOTION_TICK_S):
                return
            now = time.monotonic()
            if not self.knobs.runstopped:
                elapsed += now - last
            last = now
            with self._lock:
                if gen != self._motion_gen:
                    return  # superseded by a newer goal
                self._pose = at(reach * min(1.0, elapsed / duration) if duration > 0 else reach)
        with self._lock:
            if gen != self._motion_gen:
                return
            self._pose = at(reach)
            if stall_at is not None:
                log.info(
                    "fake Stretch: motion %d stalled %.2f m from its goal (never_arrive)",
                    gen,
                    self._pose.distance_to(goal),
                )
                return  # at_goal stays false
            self._at_goal = not blocked
            self._last_motion_failed = blocked
        if blocked:
            log.info("fake Stretch: blocked %.2f m along a %.2f m move", reach * dist, dist)
