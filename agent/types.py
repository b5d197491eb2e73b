"""The shared vocabulary of the project (docs/architecture.md section 4).

Backends (sim/, robot/) import only this module from agent/. Everything here is
plain data: frozen, slotted dataclasses and one Protocol per role.

Frames and units
----------------
* World / episode frame: right-handed, z up, metres. A robot pose is ``Pose2D``
  (x_m, y_m, yaw_rad) with yaw measured counter-clockwise from +x.
* ``Observation.pose`` is relative to the pose at ``reset()``: the robot starts
  at (0, 0, 0) facing +x, +y is to its left.
* Camera frame: OpenCV convention (x right, y down, z forward along the optical
  axis). Depth is the z coordinate in that frame (not the ray length).
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

# --- task constants (docs/architecture.md section 1) -------------------------------------

FORWARD_STEP_M = 0.25
TURN_ANGLE_DEG = 30.0
MAX_STEPS = 1000
SUCCESS_DISTANCE_M = 1.0  # to the object; implemented via goal viewpoints
VIEWPOINT_SUCCESS_RADIUS_M = 0.1
ROBOT_RADIUS_M = 0.17
ROBOT_HEIGHT_M = 1.41
CAMERA_HEIGHT_M = 1.31
CAMERA_WIDTH_PX = 360
CAMERA_HEIGHT_PX = 640
CAMERA_HFOV_DEG = 42.0
GOAL_CATEGORIES: tuple[str, ...] = ("chair", "couch", "bed", "toilet", "potted plant", "tv")


class Action(enum.IntEnum):
    """The discrete action set. Values are stable: they are stored in JSON and SQLite."""

    STOP = 0
    MOVE_FORWARD = 1
    TURN_LEFT = 2
    TURN_RIGHT = 3


def wrap_angle(angle_rad: float) -> float:
    """Wrap an angle to [-pi, pi)."""
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi


@dataclass(frozen=True, slots=True)
class Pose2D:
    """A planar pose: position in metres and heading in radians (CCW from +x)."""

    x_m: float = 0.0
    y_m: float = 0.0
    yaw_rad: float = 0.0

    def compose(self, other: Pose2D) -> Pose2D:
        """``self * other``: ``other`` expressed in ``self``'s frame, returned in the parent frame."""
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        return Pose2D(
            self.x_m + c * other.x_m - s * other.y_m,
            self.y_m + s * other.x_m + c * other.y_m,
            wrap_angle(self.yaw_rad + other.yaw_rad),
        )

    def inverse(self) -> Pose2D:
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        return Pose2D(
            -(c * self.x_m + s * self.y_m),
            -(-s * self.x_m + c * self.y_m),
            wrap_angle(-self.yaw_rad),
        )

    def relative_to(self, origin: Pose2D) -> Pose2D:
        """This pose expressed in the frame of ``origin`` (``origin^-1 * self``)."""
        return origin.inverse().compose(self)

    def transform_xy(self, xy: np.ndarray) -> np.ndarray:
        """Map points (N, 2) from this pose's local frame to the parent frame."""
        xy = np.asarray(xy, dtype=np.float64)
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        rot = np.array([[c, -s], [s, c]])
        return xy @ rot.T + np.array([self.x_m, self.y_m])

    def distance_to(self, other: Pose2D) -> float:
        return math.hypot(self.x_m - other.x_m, self.y_m - other.y_m)

    def as_tuple(self) -> tuple[float, float, float]:
        return (self.x_m, self.y_m, self.yaw_rad)


@dataclass(frozen=True, slots=True)
class Intrinsics:
    """Pinhole intrinsics in pixels for an image of ``width_px`` x ``height_px``."""

    fx: float
    fy: float
    cx: float
    cy: float
    width_px: int
    height_px: int

    @staticmethod
    def from_hfov(width_px: int, height_px: int, hfov_deg: float) -> Intrinsics:
        """Square pixels, principal point at the image centre."""
        f = (width_px / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
        return Intrinsics(f, f, width_px / 2.0, height_px / 2.0, width_px, height_px)

    @staticmethod
    def from_matrix(K: np.ndarray, width_px: int, height_px: int) -> Intrinsics:
        K = np.asarray(K, dtype=np.float64)
        if K.shape != (3, 3):
            raise ValueError(f"camera matrix must be 3x3, got {K.shape}")
        return Intrinsics(float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), int(width_px), int(height_px))

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def hfov_deg(self) -> float:
        return math.degrees(2.0 * math.atan(self.width_px / (2.0 * self.fx)))

    @property
    def vfov_deg(self) -> float:
        return math.degrees(2.0 * math.atan(self.height_px / (2.0 * self.fy)))


SIM_INTRINSICS = Intrinsics.from_hfov(CAMERA_WIDTH_PX, CAMERA_HEIGHT_PX, CAMERA_HFOV_DEG)


@dataclass(frozen=True, slots=True, eq=False)
class Observation:
    """What the agent receives each step (docs/architecture.md section 1).

    rgb:        (H, W, 3) uint8, R,G,B order, egocentric camera.
    depth_m:    (H, W) float32 metres along the optical axis, aligned with ``rgb``;
                0 where the sensor has no valid reading.
    pose:       robot base pose relative to the start of the run.
    intrinsics: of ``rgb``/``depth_m``.
    camera_height_m: optical centre above the floor.
    camera_tilt_rad: pitch of the optical axis, positive looking down (0 = level).
    goal_image: (h, w, 3) uint8 RGB, any size; the same array every step of a run.
    step:       number of actions applied since reset (0 for the first observation).
    """

    rgb: np.ndarray
    depth_m: np.ndarray
    pose: Pose2D
    intrinsics: Intrinsics
    goal_image: np.ndarray
    camera_height_m: float = CAMERA_HEIGHT_M
    camera_tilt_rad: float = 0.0
    step: int = 0
    timestamp_s: float = 0.0

    def __post_init__(self) -> None:
        if self.rgb.ndim != 3 or self.rgb.shape[2] != 3 or self.rgb.dtype != np.uint8:
            raise ValueError(f"rgb must be (H, W, 3) uint8, got {self.rgb.shape} {self.rgb.dtype}")
        if self.depth_m.shape != self.rgb.shape[:2]:
            raise ValueError(f"depth {self.depth_m.shape} does not match rgb {self.rgb.shape[:2]}")
        if self.depth_m.dtype != np.float32:
            raise ValueError(f"depth_m must be float32, got {self.depth_m.dtype}")
        if (self.intrinsics.width_px, self.intrinsics.height_px) != (self.rgb.shape[1], self.rgb.shape[0]):
            raise ValueError("intrinsics size does not match the image")
        if self.goal_image.ndim != 3 or self.goal_image.shape[2] != 3 or self.goal_image.dtype != np.uint8:
            raise ValueError("goal_image must be (h, w, 3) uint8")


class BackendError(RuntimeError):
    """A backend cannot go on (robot disconnected, runstopped, simulator failure).

    ``reason`` is a short machine-readable code (``disconnected``, ``runstopped``,
    ``not_homed``, ``ack_timeout``, ``move_failed``, ...); the message is for people.
    """

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


@runtime_checkable
class Backend(Protocol):
    """A robot, real or simulated (docs/architecture.md section 4).

    reset() starts a run and returns the first observation (pose (0, 0, 0)).
    observe() returns the current observation without acting.
    apply() executes one action; STOP ends the run. Raises BackendError when the
    backend cannot go on. close() releases resources and is idempotent.
    """

    def reset(self) -> Observation: ...

    def observe(self) -> Observation: ...

    def apply(self, action: Action) -> None: ...

    def close(self) -> None: ...


# --- what the agent says about each step (read by the console and evaluation) ---


def grid_xy_to_ij(xy_m: np.ndarray, origin_xy_m: tuple[float, float], resolution_m: float) -> np.ndarray:
    """(N, 2) metres -> (N, 2) int64 (i, j) of the containing cells of a grid whose cell
    (0, 0) has its corner at ``origin_xy_m``; rows follow y, columns follow x. May fall
    outside the grid."""
    xy_m = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
    j = np.floor((xy_m[:, 0] - origin_xy_m[0]) / resolution_m).astype(np.int64)
    i = np.floor((xy_m[:, 1] - origin_xy_m[1]) / resolution_m).astype(np.int64)
    return np.stack([i, j], axis=1)


def grid_ij_to_xy(ij: np.ndarray, origin_xy_m: tuple[float, float], resolution_m: float) -> np.ndarray:
    """(N, 2) (i, j) -> (N, 2) float64 metres of the cell centres (inverse of ``grid_xy_to_ij``)."""
    ij = np.asarray(ij, dtype=np.float64).reshape(-1, 2)
    x = origin_xy_m[0] + (ij[:, 1] + 0.5) * resolution_m
    y = origin_xy_m[1] + (ij[:, 0] + 0.5) * resolution_m
    return np.stack([x, y], axis=1)


@dataclass(frozen=True, slots=True, eq=False)
class MapSnapshot:
    """A copy of the agent's top-down map. All layers are (H, W) bool in grid order:
    row i grows with world y, column j grows with world x (``ij_grid``); cell (i, j)
    covers x in [origin_x + j*res, origin_x + (j+1)*res), same for y with i.
    World here is the run's start-relative frame."""

    resolution_m: float
    origin_xy_m: tuple[float, float]
    obstacle: np.ndarray
    explored: np.ndarray
    visited: np.ndarray
    collision: np.ndarray
    goal: np.ndarray
    frontier: np.ndarray
    blacklist: np.ndarray | None = None

    def xy_to_ij(self, xy_m: np.ndarray) -> np.ndarray:
        return grid_xy_to_ij(xy_m, self.origin_xy_m, self.resolution_m)

    def ij_to_xy(self, ij: np.ndarray) -> np.ndarray:
        return grid_ij_to_xy(ij, self.origin_xy_m, self.resolution_m)


@dataclass(frozen=True, slots=True)
class CandidateInfo:
    """A goal candidate as the agent holds it (for the console and failure analysis).

    state: ``potential`` (evidence below the detection threshold), ``confirmed`` (detected,
    and verified when verification is on) or ``rejected`` (blacklisted on the map).
    xy_m: centroid of its goal points, start-relative frame; n_views: frames that added points
    to it; best_score: the highest re-ID score among them; distance_m: robot to the centroid now;
    why: for a rejected one, why the policy gave it up (its latest rejection).
    """

    id: int
    state: str
    xy_m: tuple[float, float]
    n_views: int
    best_score: float
    distance_m: float
    why: str | None = None


@dataclass(frozen=True, slots=True, eq=False)
class AgentRecord:
    """A read-only account of one agent step: what it did and why.

    mode: e.g. ``look_around``, ``explore``, ``approach``, ``verify``, ``stopped``.
    event: what happened, as a stable name (``agent.events.Event``), and context: what it was
        decided in (``agent.events.Context``: the last resort, the deadline, the second look, ...);
        ``reason`` is written from them for people, and nothing parses ``reason``.
    reid_score: score of this frame against the goal (None if re-ID did not run; 0 when the
        gate skipped the full matcher).
    reid_full_matcher: whether the full (learned) matcher ran on this frame (None: no re-ID).
    reid_gate_score: the cheap first-stage score that decided it (None: gate off or no re-ID).
    reid_exit_score: the gate's second stage, LighterGlue's score after its exit layer (None: not
        computed: the first stage stopped the frame, the stage is off, or the frame got every layer
        without it, as near a candidate).
    matches_goal_xy / matches_obs_xy: (N, 2) float32 pixel coordinates (x, y) of the
        matched keypoints in the goal image and the egocentric image.
    goal_points_xyz: (M, 3) float32 goal points in the start-relative frame, metres.
    plan_xy_m: (K, 2) float32 planned path in the start-relative frame.
    timings_ms: per part (``mapping``, ``reid``, ``localisation``, ``planning``, ``total``).
    candidates: every goal candidate the agent knows (``CandidateInfo``), rejected ones included.
    candidate_id: the id of the candidate this step's decision is about (None: none).
    """

    step: int
    action: Action
    pose: Pose2D
    mode: str
    reason: str
    event: str | None = None  # the decision's event (``agent.events.Event`` value); reason is its prose
    context: tuple[str, ...] = ()  # the contexts it was decided in (``agent.events.Context`` values), outermost first
    reid_score: float | None = None
    reid_tau: float | None = None
    reid_full_matcher: bool | None = None
    reid_gate_score: float | None = None
    reid_exit_score: float | None = None
    goal_detected: bool = False
    matches_goal_xy: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.float32))
    matches_obs_xy: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.float32))
    goal_points_xyz: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    target_xy_m: tuple[float, float] | None = None
    target_kind: str | None = None  # "frontier" | "goal" | None
    plan_xy_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.float32))
    map: MapSnapshot | None = None
    timings_ms: Mapping[str, float] = field(default_factory=dict)
    planner_error: str | None = None
    candidates: tuple[CandidateInfo, ...] = ()
    candidate_id: int | None = None


@runtime_checkable
class Agent(Protocol):
    """An agent: reset with the goal image, then one action per observation."""

    def reset(self, goal_image: np.ndarray) -> None: ...

    def act(self, obs: Observation) -> Action: ...

    @property
    def last_record(self) -> AgentRecord | None: ...
