"""Realism profiles: a real Stretch's senses and motion around the exact simulator (issue 30).

The simulator renders exact depth and colour at exact poses, and moves land exactly. A
``RealismProfile`` names what a real robot adds, one switchable component each:

* ``depth``: a RealSense D435i at the Stretch's head. Error grows with range squared (Intel's
  stereo RMS formula, in the disparity domain, partly correlated over patches as a stereo
  matcher's window makes it), a minimum and maximum range, quantisation to the sensor's depth
  unit, no reading in the band a near edge hides from the second imager (stereo occlusion),
  flying pixels and drop-outs at depth edges, drop-outs on dark surfaces and a few random holes;
* ``rgb``: the colour image as the bridge delivers it: shot and read noise, exposure and
  white-balance drift between frames, JPEG;
* ``actuation``: moves that land short or long, turns off by a degree or two, sideways drift
  while driving and an occasional wheel slip (collisions as in the exact simulator);
* ``pose``: the agent receives an estimated pose (wheel odometry that drifts, corrected every
  few actions by a lidar localiser that leaves a small residual, so the estimate jumps); the
  metrics keep the true pose;
* ``goal_photo``: the goal view processed like a phone photo (exposure, white balance, a 4:3
  crop in portrait or landscape, slight blur, JPEG).

The numbers and where each comes from: docs/realism.md. Noise is seeded per run
(``Realism.seed`` and the episode id) and each component draws from its own stream, so the
same episode and seed give the same noise and switching one component off leaves the others'
noise unchanged. ``clean`` is the exact simulator (the benchmark's headline).
"""

from __future__ import annotations

import dataclasses
import math
import zlib
from collections.abc import Iterable
from dataclasses import dataclass, field

import cv2
import numpy as np

from agent.types import FORWARD_STEP_M, TURN_ANGLE_DEG, Action, Pose2D, wrap_angle

COMPONENTS = ("depth", "rgb", "actuation", "pose", "goal_photo")


@dataclass(frozen=True, slots=True)
class DepthModel:
    """A stereo depth camera (defaults: RealSense D435i as the Stretch streams it; docs/realism.md)."""

    baseline_m: float = 0.050  # D435 stereo baseline
    focal_px: float = 0.0  # depth imager focal length in this image's pixels; 0: the render's own fx
    native_focal_px: float = 383.0  # depth imager focal length at 640 x 480, the Stretch's stream (noise scale)
    subpixel: float = 0.08  # RMS disparity error in native pixels (Intel's typical figure)
    correlated_share: float = 0.5  # share of the disparity variance in a low-frequency field
    correlated_cell_px: int = 16  # size of that field's cells in image pixels
    disparity_step_px: float = 1.0 / 32.0  # subpixel resolution of the disparity (native pixels)
    min_range_m: float = 0.17  # Min-Z at 640 x 480 (the largest disparity the matcher searches)
    max_range_m: float = 5.0  # the bridge's far limit: no reading beyond
    depth_unit_m: float = 0.001  # the driver's depth unit (16-bit millimetres)
    edge_ratio: float = 0.10  # a depth edge: neighbours differ by more than this share of the depth
    edge_invalid_prob: float = 0.5  # an edge pixel has no reading
    flying_prob: float = 0.3  # an edge pixel reads a blend of the near and far surface
    dark_level: float = 0.10  # mean RGB (0-1) below which a surface is dark for the projector
    dark_invalid_prob: float = 0.6
    holes_per_frame: float = 8.0  # mean number of random hole blobs (about 1% of the pixels)
    hole_radius_px: tuple[int, int] = (3, 15)
    baseline_axis: int = 0  # image axis of the stereo baseline (0: rows; the head camera is portrait)


@dataclass(frozen=True, slots=True)
class RgbModel:
    """The colour image as the bridge sends it."""

    read_noise_dn: float = 2.0  # sensor read noise (8-bit levels)
    shot_noise_gain: float = 0.03  # variance per level of signal (photon noise): about 2.8 levels at mid-grey
    gain_step: float = 0.02  # per-frame log-exposure random walk
    gain_bound: float = 0.1  # |log gain| bound (auto-exposure keeps it within about 10%)
    wb_step: float = 0.008  # per-frame per-channel log white-balance random walk
    wb_bound: float = 0.05
    jpeg_quality: int = 90


@dataclass(frozen=True, slots=True)
class ActuationModel:
    """Where a discrete move lands (the commanded 0.25 m / 30 deg)."""

    # habitat-sim's LoCoBot "Proportional" noise model at the Habitat Challenge's multiplier 0.5,
    # without its sign-corrected lateral and heading biases (a symmetric base), samples cut at 3 SD
    forward_mean_m: float = 0.008  # a 0.25 m move overshoots by this on average
    forward_sd_m: float = 0.042
    lateral_sd_m: float = 0.076  # sideways drift during a forward move
    forward_yaw_sd_deg: float = 4.6  # heading change during a forward move
    turn_mean_deg: float = 1.2  # a 30 deg turn overshoots by this on average
    turn_sd_deg: float = 3.7
    cut_sd: float = 3.0
    slip_prob: float = 0.02  # a forward move in which the wheels slip (assumed)
    slip_travel: tuple[float, float] = (0.0, 0.6)  # share of the move actually made when slipping


@dataclass(frozen=True, slots=True)
class PoseModel:
    """The pose the agent receives: odometry integrated between a localiser's corrections."""

    odom_dist_sd_frac: float = 0.02  # wheel odometry's distance error, share of distance driven
    odom_yaw_sd_deg_per_m: float = 1.0  # heading drift per metre driven
    odom_turn_sd_frac: float = 0.02  # turn error, share of the angle turned
    localise_every: int = 5  # actions between localiser corrections (0: odometry only)
    localise_xy_sd_m: float = 0.03  # the localiser's residual error
    localise_yaw_sd_deg: float = 1.5


@dataclass(frozen=True, slots=True)
class GoalPhotoModel:
    """A phone's photo of the goal, made from the rendered goal view."""

    exposure_log_range: float = 0.35  # gain exp(U(-r, r)): +-0.5 EV
    wb_log_range: float = 0.08  # per channel
    gamma_range: tuple[float, float] = (0.9, 1.1)
    blur_sigma_px: tuple[float, float] = (0.3, 1.2)
    portrait_prob: float = 0.5  # 3:4 portrait, else 4:3 landscape
    crop_jitter: float = 0.05  # the crop's centre moves by up to this share of the image
    jpeg_quality: tuple[int, int] = (85, 95)


@dataclass(frozen=True, slots=True)
class RealismProfile:
    """A named set of components; None: that part is exact."""

    name: str
    depth: DepthModel | None = None
    rgb: RgbModel | None = None
    actuation: ActuationModel | None = None
    pose: PoseModel | None = None
    goal_photo: GoalPhotoModel | None = None

    @property
    def components(self) -> tuple[str, ...]:
        return tuple(c for c in COMPONENTS if getattr(self, c) is not None)

    @property
    def clean(self) -> bool:
        return not self.components

    def only(self, names: Iterable[str]) -> RealismProfile:
        """This profile with only the named components (the others exact)."""
        keep = set(names)
        unknown = keep - set(COMPONENTS)
        if unknown:
            raise ValueError(f"unknown realism component(s) {sorted(unknown)}; known: {', '.join(COMPONENTS)}")
        missing = [c for c in keep if getattr(self, c) is None]
        if missing:
            raise ValueError(f"profile {self.name!r} has no {', '.join(sorted(missing))} component")
        label = "+".join(c for c in COMPONENTS if c in keep)
        return dataclasses.replace(self, name=f"{self.name}[{label}]", **{c: None for c in COMPONENTS if c not in keep})


PROFILES: dict[str, RealismProfile] = {
    "clean": RealismProfile("clean"),
    "stretch": RealismProfile(
        "stretch",
        depth=DepthModel(),
        rgb=RgbModel(),
        actuation=ActuationModel(),
        pose=PoseModel(),
        goal_photo=GoalPhotoModel(),
    ),
}


def get_profile(name: str, only: Iterable[str] | None = None) -> RealismProfile:
    """A named profile, optionally with only some components (``--realism-only``)."""
    if name not in PROFILES:
        raise ValueError(f"unknown realism profile {name!r}; known: {', '.join(PROFILES)}")
    profile = PROFILES[name]
    return profile.only(only) if only else profile


@dataclass(frozen=True, slots=True)
class Realism:
    """A profile and the seed of its noise (the same profile, seed and run key: the same noise)."""

    profile: RealismProfile = field(default_factory=lambda: PROFILES["clean"])
    seed: int = 0

    def describe(self) -> dict:
        """What an evaluation record stores about it."""
        return {"profile": self.profile.name, "components": list(self.profile.components), "seed": self.seed}

    def start(self, key: str) -> RealismRun | None:
        """The noise of one run (``key``: the episode id or another stable name); None when clean."""
        return None if self.profile.clean else RealismRun(self.profile, self.seed, key)


def _cut_normal(rng: np.random.Generator, cut: float) -> float:
    """A standard normal sample clipped at +-``cut``."""
    return float(np.clip(rng.standard_normal(), -cut, cut))


def _streams(seed: int, key: str) -> dict[str, np.random.Generator]:
    root = np.random.SeedSequence([seed & 0xFFFFFFFF, zlib.crc32(key.encode())])
    return {name: np.random.default_rng(child) for name, child in zip(COMPONENTS, root.spawn(len(COMPONENTS)))}


class RealismRun:
    """The noise state of one run: per-frame colour drift, the pose estimate."""

    def __init__(self, profile: RealismProfile, seed: int, key: str) -> None:
        self.profile = profile
        self._rng = _streams(seed, key)
        self._log_gain = 0.0
        self._log_wb = np.zeros(3)
        self.estimate_world: Pose2D | None = None  # the agent's belief of its world pose

    # --- motion ---
    def actual_motion(self, action: Action) -> tuple[float, float, float, bool]:
        """(forward_m, lateral_m, turn_rad, slipped) that a commanded action really makes."""
        a = self.profile.actuation
        if action == Action.MOVE_FORWARD:
            if a is None:
                return FORWARD_STEP_M, 0.0, 0.0, False
            rng = self._rng["actuation"]
            d = FORWARD_STEP_M + a.forward_mean_m + a.forward_sd_m * _cut_normal(rng, a.cut_sd)
            lat = a.lateral_sd_m * _cut_normal(rng, a.cut_sd)
            yaw = math.radians(a.forward_yaw_sd_deg) * _cut_normal(rng, a.cut_sd)
            slipped = bool(rng.random() < a.slip_prob)
            if slipped:
                share = rng.uniform(*a.slip_travel)
                d, lat, yaw = d * share, lat * share, yaw * share
            return max(d, 0.0), lat, yaw, slipped
        if action in (Action.TURN_LEFT, Action.TURN_RIGHT):
            sign = 1.0 if action == Action.TURN_LEFT else -1.0
            turn_deg = TURN_ANGLE_DEG
            if a is not None:
                turn_deg += a.turn_mean_deg + a.turn_sd_deg * _cut_normal(self._rng["actuation"], a.cut_sd)
            return 0.0, 0.0, sign * math.radians(turn_deg), False
        return 0.0, 0.0, 0.0, False

    def start_estimate(self, start_world: Pose2D) -> None:
        self.estimate_world = start_world

    def update_estimate(
        self, action: Action, before: Pose2D, after: Pose2D, slipped: bool, commanded: Pose2D, step: int
    ) -> None:
        """Integrate the odometry of one action (``commanded``: the motion the wheels were told to
        make, in the robot's frame); every ``localise_every`` actions the localiser corrects."""
        p = self.profile.pose
        assert self.estimate_world is not None
        if p is None:
            self.estimate_world = after
            return
        rng = self._rng["pose"]
        true_delta = after.relative_to(before)
        # a slipping wheel turns as commanded: the odometry counts the commanded move
        delta = commanded if slipped else true_delta
        dist = math.hypot(delta.x_m, delta.y_m)
        fwd = delta.x_m * (1.0 + p.odom_dist_sd_frac * rng.standard_normal())
        yaw = delta.yaw_rad
        yaw += math.radians(p.odom_yaw_sd_deg_per_m) * math.sqrt(dist) * rng.standard_normal()
        yaw += abs(delta.yaw_rad) * p.odom_turn_sd_frac * rng.standard_normal()
        measured = Pose2D(fwd, delta.y_m, wrap_angle(yaw))
        self.estimate_world = self.estimate_world.compose(measured)
        if p.localise_every > 0 and step % p.localise_every == 0:
            self.estimate_world = after.compose(
                Pose2D(
                    p.localise_xy_sd_m * rng.standard_normal(),
                    p.localise_xy_sd_m * rng.standard_normal(),
                    math.radians(p.localise_yaw_sd_deg) * rng.standard_normal(),
                )
            )

    # --- sensors ---
    def depth(self, depth_m: np.ndarray, rgb: np.ndarray, fx_px: float) -> np.ndarray:
        m = self.profile.depth
        return depth_m if m is None else noisy_depth(depth_m, rgb, fx_px, m, self._rng["depth"])

    def rgb(self, rgb: np.ndarray) -> np.ndarray:
        m = self.profile.rgb
        if m is None:
            return rgb
        self._drift_colour(m)
        return noisy_rgb(rgb, m, np.exp(self._log_gain + self._log_wb), self._rng["rgb"])

    def skip_frames(self, frames: int) -> None:
        """Let the exposure and white-balance drift run on for ``frames`` frames that are not
        delivered (the calibration's robot frames: a frame from within a run, not its first)."""
        m = self.profile.rgb
        if m is None:
            return
        for _ in range(frames):
            self._drift_colour(m)

    def _drift_colour(self, m: RgbModel) -> None:
        """One frame's step of the exposure and white-balance random walks."""
        rng = self._rng["rgb"]
        self._log_gain = float(
            np.clip(self._log_gain + m.gain_step * rng.standard_normal(), -m.gain_bound, m.gain_bound)
        )
        self._log_wb = np.clip(self._log_wb + m.wb_step * rng.standard_normal(3), -m.wb_bound, m.wb_bound)

    def goal_photo(self, image: np.ndarray) -> np.ndarray:
        m = self.profile.goal_photo
        return image if m is None else phone_photo(image, m, self._rng["goal_photo"])


# --- the models, as functions of arrays (tests call them directly) -------------------------


def _shift(a: np.ndarray, k: int, axis: int, fill: float) -> np.ndarray:
    """``a`` moved by k pixels along ``axis`` (positive: towards higher indices), edges filled."""
    out = np.full_like(a, fill)
    n = a.shape[axis]
    if abs(k) >= n:
        return out
    src = [slice(None)] * a.ndim
    dst = [slice(None)] * a.ndim
    if k >= 0:
        src[axis], dst[axis] = slice(0, n - k), slice(k, n)
    else:
        src[axis], dst[axis] = slice(-k, n), slice(0, n + k)
    out[tuple(dst)] = a[tuple(src)]
    return out


def stereo_occlusion(depth_m: np.ndarray, focal_px: float, baseline_m: float, axis: int) -> np.ndarray:
    """(H, W) bool: pixels the second imager cannot see because a nearer surface beside them
    (along the baseline) hides them. A pixel with disparity d at position u is hidden when a
    pixel at u + k has disparity greater than d + k (it lands on or past u in the other view)."""
    valid = depth_m > 0
    disp = np.where(valid, focal_px * baseline_m / np.maximum(depth_m, 1e-6), 0.0).astype(np.float32)
    max_k = int(math.ceil(float(disp.max()))) if valid.any() else 0
    hidden = np.zeros(depth_m.shape, bool)
    for k in range(1, min(max_k, depth_m.shape[axis] - 1) + 1):
        hidden |= _shift(disp, -k, axis, 0.0) > disp + k
    return hidden & valid


def depth_edges(depth_m: np.ndarray, ratio: float) -> np.ndarray:
    """(H, W) bool: pixels whose 4-neighbours' depth differs by more than ``ratio`` of the larger."""
    z = np.asarray(depth_m, np.float32)
    edge = np.zeros(z.shape, bool)
    for axis in (0, 1):
        a = z[:-1] if axis == 0 else z[:, :-1]
        b = z[1:] if axis == 0 else z[:, 1:]
        jump = (a > 0) & (b > 0) & (np.abs(a - b) > ratio * np.maximum(a, b))
        if axis == 0:
            edge[:-1] |= jump
            edge[1:] |= jump
        else:
            edge[:, :-1] |= jump
            edge[:, 1:] |= jump
    return edge


def noisy_depth(
    depth_m: np.ndarray, rgb: np.ndarray, fx_px: float, m: DepthModel, rng: np.random.Generator
) -> np.ndarray:
    """The exact depth as the modelled stereo camera would return it (0: no reading)."""
    z = np.asarray(depth_m, np.float32)
    h, w = z.shape
    valid = (z >= m.min_range_m) & (z <= m.max_range_m)
    focal = m.focal_px or fx_px
    # stereo: the error is in disparity (native pixels); depth error = z^2 / (f b) * disparity error
    sd_native = m.subpixel
    white = rng.standard_normal((h, w), dtype=np.float32) * sd_native * math.sqrt(1.0 - m.correlated_share)
    cell = max(1, m.correlated_cell_px)
    coarse = rng.standard_normal((h // cell + 2, w // cell + 2), dtype=np.float32)
    up = np.asarray(cv2.resize(coarse, (w + 2 * cell, h + 2 * cell), interpolation=cv2.INTER_LINEAR), np.float32)
    smooth = up[cell : cell + h, cell : cell + w]
    smooth = smooth / max(float(smooth.std()), 1e-6)  # interpolation lowers the variance: back to unit
    err_disp = white + smooth * sd_native * math.sqrt(m.correlated_share)
    fb = m.native_focal_px * m.baseline_m
    with np.errstate(divide="ignore", invalid="ignore"):
        disp = np.where(valid, fb / np.maximum(z, 1e-6), 0.0) + err_disp
        disp = np.round(disp / m.disparity_step_px) * m.disparity_step_px
        out = np.where(valid & (disp > 0), fb / np.maximum(disp, 1e-6), 0.0).astype(np.float32)
    # edges: the matcher's window straddles two surfaces (flying pixels) or finds no match
    edge = depth_edges(z, m.edge_ratio)
    u = rng.random((h, w), dtype=np.float32)
    drop = edge & (u < m.edge_invalid_prob)
    flying = edge & ~drop & (u < m.edge_invalid_prob + m.flying_prob)
    ys, xs = np.nonzero(flying)
    if len(ys):
        pad = np.pad(z, 1)
        far = np.maximum.reduce([pad[ys, xs + 1], pad[ys + 2, xs + 1], pad[ys + 1, xs], pad[ys + 1, xs + 2]])
        t = rng.random(len(ys), dtype=np.float32)
        out[ys, xs] = (1 - t) * out[ys, xs] + t * far
    drop |= stereo_occlusion(z, focal, m.baseline_m, m.baseline_axis)
    # dark surfaces return too little of the projector's pattern
    brightness = np.asarray(rgb, np.float32).mean(axis=2) / 255.0
    drop |= (brightness < m.dark_level) & (rng.random((h, w), dtype=np.float32) < m.dark_invalid_prob)
    # random holes (specular spots, texture-less patches the projector misses)
    for _ in range(rng.poisson(m.holes_per_frame)):
        cy, cx = rng.integers(0, h), rng.integers(0, w)
        r = int(rng.integers(m.hole_radius_px[0], m.hole_radius_px[1] + 1))
        cv2.circle(drop.view(np.uint8), (int(cx), int(cy)), r, 1, -1)
    out[drop | ~valid] = 0.0
    out[(out < m.min_range_m) | (out > m.max_range_m)] = 0.0
    return (np.round(out / m.depth_unit_m) * m.depth_unit_m).astype(np.float32)


def noisy_rgb(rgb: np.ndarray, m: RgbModel, gains: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Exposure and white balance (``gains`` per channel), sensor noise, then JPEG."""
    img = np.asarray(rgb, np.float32) * gains[None, None, :].astype(np.float32)
    sd = np.sqrt(m.read_noise_dn**2 + m.shot_noise_gain * np.clip(img, 0, 255))
    img += sd * rng.standard_normal(img.shape, dtype=np.float32)
    return jpeg(np.clip(np.round(img), 0, 255).astype(np.uint8), m.jpeg_quality)


def jpeg(rgb: np.ndarray, quality: int) -> np.ndarray:
    """``rgb`` through a JPEG encode and decode at ``quality``."""
    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    decoded = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    if decoded is None:
        raise RuntimeError("JPEG decoding failed")
    return cv2.cvtColor(decoded, cv2.COLOR_BGR2RGB)


def phone_photo(image: np.ndarray, m: GoalPhotoModel, rng: np.random.Generator) -> np.ndarray:
    """A rendered goal view made to look like a phone's photo of it."""
    img = np.asarray(image, np.float32) / 255.0
    h, w = img.shape[:2]
    # a 4:3 crop (portrait 3:4 or landscape 4:3) of the largest size that fits, near the centre
    portrait = rng.random() < m.portrait_prob
    ch, cw = (h, min(w, round(h * 3 / 4))) if portrait else (min(h, round(w * 3 / 4)), w)
    if ch > h or cw > w:
        ch, cw = h, w
    cy = h / 2 + rng.uniform(-m.crop_jitter, m.crop_jitter) * h
    cx = w / 2 + rng.uniform(-m.crop_jitter, m.crop_jitter) * w
    y0 = int(np.clip(round(cy - ch / 2), 0, h - ch))
    x0 = int(np.clip(round(cx - cw / 2), 0, w - cw))
    img = img[y0 : y0 + ch, x0 : x0 + cw]
    gain = math.exp(rng.uniform(-m.exposure_log_range, m.exposure_log_range))
    wb = np.exp(rng.uniform(-m.wb_log_range, m.wb_log_range, 3)).astype(np.float32)
    img = np.clip(img * gain * wb[None, None, :], 0.0, 1.0) ** rng.uniform(*m.gamma_range)
    sigma = rng.uniform(*m.blur_sigma_px)
    img = cv2.GaussianBlur(img, (0, 0), sigma)
    out = np.clip(np.round(img * 255.0), 0, 255).astype(np.uint8)
    return jpeg(np.ascontiguousarray(out), int(rng.integers(m.jpeg_quality[0], m.jpeg_quality[1] + 1)))
