"""Goal images: 512x512 renders of one instance as the main subject (docs/architecture.md sections 1 and 8).

A goal camera is sampled like a person photographing the object: eye height
0.8-1.7 m, 1-3 m from the object (more for large ones), mostly from its front
half, looking at its centre with a little jitter, HFOV 60-90 deg. A sample is
rejected when the instance is small (< ``min_coverage`` of the image), off-centre,
occluded (few rays from the eye reach it), cut by the image border, or smaller in
the image than another goal instance; images
that also show a same-category instance are capped (a budget per call).

``sample_goal_images`` is the reusable per-instance sampler (episodes, the
console's gallery, the re-ID calibration pairs).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from sim.camera import GOAL_IMAGE_PX, CameraSpec, look_at_angles
from sim.geometry import FootprintIndex
from sim.navigation import instance_sample_points

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class GoalCamera:
    eye_xyz_m: tuple[float, float, float]
    yaw_rad: float
    pitch_rad: float  # positive looking down
    hfov_deg: float
    size_px: int = GOAL_IMAGE_PX

    @property
    def spec(self) -> CameraSpec:
        return CameraSpec(self.size_px, self.size_px, self.hfov_deg, self.eye_xyz_m[2], self.pitch_rad)


@dataclass(frozen=True, slots=True, eq=False)
class GoalImage:
    """rgb: (512, 512, 3) uint8; mask: (512, 512) bool pixels of the instance."""

    instance_id: int
    rgb: np.ndarray
    mask: np.ndarray
    camera: GoalCamera
    coverage: float
    shows_distractor: bool


@dataclass(frozen=True, slots=True)
class GoalSamplerConfig:
    min_coverage: float = 0.07
    max_coverage: float = 0.6
    max_centre_offset: float = 0.18  # mask centroid from the image centre, fraction of the size
    min_visible_rays: float = 0.5  # fraction of rays from the eye that reach the instance first
    max_border_fraction: float = 0.5  # of the mask's bounding box sides touching the border
    distractor_min_pixels: float = 0.004  # a same-category instance counts when it covers this share
    max_distractor_share: float = 0.2
    distance_m: tuple[float, float] = (1.0, 3.0)
    eye_height_m: tuple[float, float] = (0.8, 1.7)
    hfov_deg: tuple[float, float] = (60.0, 90.0)
    front_probability: float = 0.75
    same_room_share: float = 0.7  # of the attempts, in which the eye must be in the object's room
    attempts_per_image: int = 60


def _propose(rng: np.random.Generator, obj, cfg: GoalSamplerConfig) -> tuple[np.ndarray, np.ndarray, float]:
    cx, cy, cz = obj.center_xyz_m()
    x0, y0, x1, y1 = obj.bounds_xy_m()
    radius = 0.5 * math.hypot(x1 - x0, y1 - y0)
    yaw = obj.pose_xy_yaw[2]
    front = math.atan2(math.cos(yaw), -math.sin(yaw))  # local +y in the world
    if rng.uniform() < cfg.front_probability:
        az = front + rng.uniform(-1.3, 1.3)
    else:
        az = rng.uniform(-math.pi, math.pi)
    # bigger objects are photographed from further away to keep them in frame
    dist = max(rng.uniform(*cfg.distance_m) * max(1.0, radius / 0.6), radius + 0.4)
    eye = np.array([cx + dist * math.cos(az), cy + dist * math.sin(az), rng.uniform(*cfg.eye_height_m)])
    jitter = np.array([x1 - x0, y1 - y0, max(cz, 0.1)]) * rng.uniform(-0.08, 0.08, 3)
    return eye, np.array([cx, cy, cz]) + jitter, float(rng.uniform(*cfg.hfov_deg))


def sample_goal_images(
    world,
    instance_id: int,
    count: int,
    seed: int | tuple[int, ...],
    cfg: GoalSamplerConfig = GoalSamplerConfig(),
    distractor_budget: int | None = None,
) -> list[GoalImage]:
    """Up to ``count`` accepted goal images of one instance (fewer if the attempts run out).

    Deterministic in ``seed``. ``distractor_budget``: how many of them may show another
    instance of the same category (default ``floor(max_distractor_share * count)``)."""
    rng = np.random.default_rng(seed)
    obj = world.home.instance(instance_id)
    same = [o.object_id for o in world.home.instances if o.category == obj.category and o.object_id != instance_id]
    budget = int(math.floor(cfg.max_distractor_share * count)) if distractor_budget is None else distractor_budget
    targets = instance_sample_points(obj)
    if not hasattr(world, "_goal_eye_index"):
        x0, y0, x1, y1 = world.home.bounds_m
        # the photographer's eye: clear of walls and anything up to 2 m tall by 0.12 m
        world._goal_eye_index = FootprintIndex(world.home.solid_footprints(), (x0, y0, x1, y1), 0.12, 2.0)
    eye_index: FootprintIndex = world._goal_eye_index
    out: list[GoalImage] = []
    home_room = world.home.rooms[obj.room_index] if 0 <= obj.room_index < len(world.home.rooms) else None
    attempts = count * cfg.attempts_per_image
    for attempt in range(attempts):
        if len(out) >= count:
            break
        eye, target, hfov = _propose(rng, obj, cfg)
        eye_room = world.home.room_at(float(eye[0]), float(eye[1]))
        if eye_index.collides(float(eye[0]), float(eye[1])) or eye_room is None:
            continue
        if (
            home_room is not None
            and eye_room is not home_room
            and not home_room.contains(float(eye[0]), float(eye[1]))
            and attempt < cfg.same_room_share * attempts
        ):
            continue  # people photograph an object from its own room; through a doorway only if they must
        hits = world.ray_objects(np.repeat(eye[None], len(targets), axis=0), targets)
        if np.mean(hits == instance_id) < cfg.min_visible_rays:
            continue
        yaw, pitch = look_at_angles(eye, target)
        cam = GoalCamera(tuple(float(v) for v in eye), yaw, pitch, hfov)  # type: ignore[arg-type]
        render = world.render_view(eye, yaw, pitch, cam.spec)
        mask = render.instance_ids == instance_id
        coverage = float(mask.mean())
        if not cfg.min_coverage <= coverage <= cfg.max_coverage:
            continue
        ids = render.instance_ids[render.instance_ids >= 0]
        if np.bincount(ids).argmax() != instance_id:
            continue  # another goal instance (e.g. a chair in front of the couch) is the bigger subject
        rows, cols = np.nonzero(mask)
        n = cam.size_px
        if abs(cols.mean() / n - 0.5) > cfg.max_centre_offset or abs(rows.mean() / n - 0.5) > cfg.max_centre_offset:
            continue
        border = [rows.min() == 0, rows.max() == n - 1, cols.min() == 0, cols.max() == n - 1]
        if sum(border) / 4.0 > cfg.max_border_fraction:
            continue
        shows = bool(same) and float(np.isin(render.instance_ids, same).mean()) >= cfg.distractor_min_pixels
        if shows:
            if budget <= 0:
                continue
            budget -= 1
        out.append(GoalImage(instance_id, render.rgb, mask, cam, coverage, shows))
    if len(out) < count:
        log.debug("instance %d: %d of %d goal images accepted", instance_id, len(out), count)
    return out
