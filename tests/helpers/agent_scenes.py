"""Hand-built scenes for the agent's unit tests: an analytic ray caster for box rooms."""

from __future__ import annotations

import math

import numpy as np

from agent.projection import camera_rays_base
from agent.types import CAMERA_HEIGHT_M, Intrinsics, Observation, Pose2D

SMALL_INTRINSICS = Intrinsics.from_hfov(90, 160, 42.0)  # the sim camera's shape at 1/4 size


def render_depth(
    boxes: list[tuple[float, float, float, float, float]],
    pose: Pose2D,
    intrinsics: Intrinsics = SMALL_INTRINSICS,
    camera_height_m: float = CAMERA_HEIGHT_M,
    tilt_rad: float = 0.0,
    far_m: float = 50.0,
    return_ids: bool = False,
):
    """Depth (H, W) float32 (z along the optical axis) of a floor plus axis-aligned boxes;
    0 (no reading) where a ray hits nothing within ``far_m``.

    boxes: (x_min, y_min, x_max, y_max, height_m), each standing on the floor.
    """
    h, w = intrinsics.height_px, intrinsics.width_px
    v, u = np.mgrid[0:h, 0:w]
    fwd, left, up = camera_rays_base(u.ravel() + 0.5, v.ravel() + 0.5, intrinsics, tilt_rad)
    c, s = math.cos(pose.yaw_rad), math.sin(pose.yaw_rad)
    # one contiguous array per axis: the slab test below is elementwise on each
    d = [np.ascontiguousarray(a, np.float64) for a in (c * fwd - s * left, s * fwd + c * left, up)]
    o = (pose.x_m, pose.y_m, camera_height_m)
    t = np.full(d[0].shape, far_m, np.float64)
    ids = np.full(d[0].shape, -1, np.int64)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.minimum(t, np.where(d[2] < 0, -o[2] / d[2], np.inf))
        for k, (x0, y0, x1, y1, hz) in enumerate(boxes):
            tmin = tmax = None
            for lo, hi, oi, di in zip((x0, y0, 0.0), (x1, y1, hz), o, d):
                t1, t2 = (lo - oi) / di, (hi - oi) / di
                near, far = np.minimum(t1, t2), np.maximum(t1, t2)
                # fmax/fmin skip the NaN of 0/0 (a ray in a face's plane), as nanmax/nanmin do
                tmin = near if tmin is None else np.fmax(tmin, near)
                tmax = far if tmax is None else np.fmin(tmax, far)
            closer = (tmax >= tmin) & (tmax > 0) & (tmin > 0) & (tmin < t)
            t = np.where(closer, tmin, t)
            ids = np.where(closer, k, ids)
    t = np.where(t >= far_m, 0.0, t)
    depth = t.reshape(h, w).astype(np.float32)
    if return_ids:
        return depth, ids.reshape(h, w)
    return depth


def room_walls(x0: float, y0: float, x1: float, y1: float, height: float = 2.5, thick: float = 0.1):
    return [
        (x0 - thick, y0 - thick, x1 + thick, y0, height),
        (x0 - thick, y1, x1 + thick, y1 + thick, height),
        (x0 - thick, y0, x0, y1, height),
        (x1, y0, x1 + thick, y1, height),
    ]


def observation(
    boxes,
    pose: Pose2D,
    intrinsics: Intrinsics = SMALL_INTRINSICS,
    rgb: np.ndarray | None = None,
    goal: np.ndarray | None = None,
    step: int = 0,
) -> Observation:
    depth = render_depth(boxes, pose, intrinsics)
    if rgb is None:
        rgb = np.zeros((intrinsics.height_px, intrinsics.width_px, 3), np.uint8)
    if goal is None:
        goal = np.zeros((64, 64, 3), np.uint8)
    return Observation(rgb=rgb, depth_m=depth, pose=pose, intrinsics=intrinsics, goal_image=goal, step=step)


class BoxWorld:
    """A tiny simulator for policy tests: box obstacles, exact depth, the task's discrete actions,
    a cylinder robot that does not slide (a blocked forward move leaves it in place)."""

    def __init__(
        self, boxes, start: Pose2D, goal_box: int, radius_m: float = 0.17, intrinsics: Intrinsics = SMALL_INTRINSICS
    ) -> None:
        self.boxes = list(boxes)
        self.start = start
        self.pose = start  # world frame
        self.goal_box = goal_box
        self.radius_m = radius_m
        self.intrinsics = intrinsics
        self.step = 0
        self._ids = None

    def collides(self, x: float, y: float) -> bool:
        for x0, y0, x1, y1, hz in self.boxes:
            if hz <= 0.0:
                continue
            cx, cy = min(max(x, x0), x1), min(max(y, y0), y1)
            if math.hypot(x - cx, y - cy) < self.radius_m:
                return True
        return False

    def observe(self) -> Observation:
        depth, ids = render_depth(self.boxes, self.pose, self.intrinsics, return_ids=True)
        self._ids = ids
        rgb = np.zeros((self.intrinsics.height_px, self.intrinsics.width_px, 3), np.uint8)
        return Observation(
            rgb=rgb,
            depth_m=depth,
            pose=self.pose.relative_to(self.start),
            intrinsics=self.intrinsics,
            goal_image=np.zeros((64, 64, 3), np.uint8),
            step=self.step,
        )

    def goal_mask(self, obs: Observation) -> np.ndarray:
        return self._ids == self.goal_box

    def goal_visible(self, obs: Observation) -> bool:
        return int(np.count_nonzero(self._ids == self.goal_box)) >= 20

    def apply(self, action) -> None:
        from agent.types import Action

        self.step += 1
        p = self.pose
        if action == Action.MOVE_FORWARD:
            nx, ny = p.x_m + 0.25 * math.cos(p.yaw_rad), p.y_m + 0.25 * math.sin(p.yaw_rad)
            if not any(
                self.collides(p.x_m + f * (nx - p.x_m), p.y_m + f * (ny - p.y_m)) for f in (0.25, 0.5, 0.75, 1.0)
            ):
                self.pose = Pose2D(nx, ny, p.yaw_rad)
        elif action == Action.TURN_LEFT:
            self.pose = p.compose(Pose2D(0, 0, math.radians(30)))
        elif action == Action.TURN_RIGHT:
            self.pose = p.compose(Pose2D(0, 0, -math.radians(30)))

    def distance_to_goal(self) -> float:
        x0, y0, x1, y1, _ = self.boxes[self.goal_box]
        cx, cy = min(max(self.pose.x_m, x0), x1), min(max(self.pose.y_m, y0), y1)
        return math.hypot(self.pose.x_m - cx, self.pose.y_m - cy)


# A room with one goal box (the localisation and candidate tests).
GOAL_BOX = (3.0, -0.3, 3.6, 0.3, 0.8)
BOXES = room_walls(-1.0, -2.0, 6.0, 2.0) + [GOAL_BOX]


def obs_and_ids(pose: Pose2D = Pose2D()) -> tuple[Observation, np.ndarray]:
    """The observation from ``pose`` in the one-box room and each pixel's box index (-1: floor)."""
    depth, ids = render_depth(BOXES, pose, return_ids=True)
    rgb = np.zeros(depth.shape + (3,), np.uint8)
    return Observation(
        rgb=rgb, depth_m=depth, pose=pose, intrinsics=SMALL_INTRINSICS, goal_image=np.zeros((64, 64, 3), np.uint8)
    ), ids


def two_rooms():
    """Room A (x -3..1) and room B (x 1..5), y -2..2, joined by a 0.9 m door at y in [-0.45, 0.45];
    the goal (a 0.6 m cube) stands in room B's far corner, hidden from the start.
    Returns (boxes, the goal's index, the decoy's index)."""
    walls = room_walls(-3.0, -2.0, 5.0, 2.0)
    walls += [(1.0, -2.0, 1.1, -0.45, 2.5), (1.0, 0.45, 1.1, 2.0, 2.5)]
    goal = (4.0, 1.0, 4.6, 1.6, 0.6)
    decoy = (-2.6, 1.2, -2.0, 1.8, 0.6)
    boxes = walls + [goal, decoy]
    return boxes, len(walls), len(walls) + 1


GOAL_RGB = (255, 0, 0)
DECOY_RGB = (0, 255, 0)


class PaintedWorld(BoxWorld):
    """BoxWorld whose frames show the goal in red and the decoy in green, so that a frame scored
    later (from the shortlist) carries what it saw."""

    def __init__(self, *a, decoy: int, **kw) -> None:
        super().__init__(*a, **kw)
        self.decoy = decoy

    def observe(self):
        obs = super().observe()
        obs.rgb[self._ids == self.goal_box] = GOAL_RGB
        obs.rgb[self._ids == self.decoy] = DECOY_RGB
        return obs
