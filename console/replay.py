"""What a finished run needs to be replayed step by step, kept in the run store.

Per step (``replay_steps``): a JPEG thumbnail of the egocentric view and a small JSON of
what the agent had in mind (goal candidates, goal points, plan, target). The map
(``replay_maps``) only every ``map_every`` steps, at the first detection, and at the last
step: each snapshot is the agent's layers bit-packed and zlib-compressed (a few kB), and a
replayed step shows the latest snapshot at or before it, with its own pose, trajectory so
far, plan and target drawn over it. Rows use the run store's connection and lock.

Writing happens on the run's worker thread (``ReplayRecorder``, fed by the artifact
writer); reading (``ReplayReader``) serves the API and the viewer.
"""

from __future__ import annotations

import io
import json
import logging
import struct
import zlib
from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache
from typing import TYPE_CHECKING, Any

import numpy as np
from PIL import Image

from agent.types import MapSnapshot, Pose2D

if TYPE_CHECKING:
    from console.session import StepRecord
    from console.store import RunStore

logger = logging.getLogger(__name__)

LAYERS = ("obstacle", "explored", "visited", "collision", "goal", "frontier", "blacklist")


@dataclass(frozen=True, slots=True)
class ReplayConfig:
    map_every: int = 10  # steps between map snapshots (plus first detection and the last step)
    thumb_width_px: int = 180  # egocentric thumbnails: 180 x 320 for the portrait sim camera
    jpeg_quality: int = 70
    max_goal_points: int = 200  # subsampled for the per-step JSON
    max_plan_points: int = 60


# --- map snapshots <-> bytes ------------------------------------------------------------


def encode_map(snapshot: MapSnapshot) -> bytes:
    """Header (JSON: shape, resolution, origin, layers present) + zlib(packbits(layers))."""
    h, w = snapshot.obstacle.shape
    present = [name for name in LAYERS if getattr(snapshot, name) is not None]
    stack = np.stack([np.asarray(getattr(snapshot, name), bool) for name in present])
    header = json.dumps(
        {"h": h, "w": w, "res": snapshot.resolution_m, "origin": list(snapshot.origin_xy_m), "layers": present}
    ).encode()
    body = zlib.compress(np.packbits(stack, axis=None).tobytes(), 6)
    return struct.pack(">I", len(header)) + header + body


def decode_map(blob: bytes) -> MapSnapshot:
    (n,) = struct.unpack(">I", blob[:4])
    header = json.loads(blob[4 : 4 + n])
    h, w, layers = int(header["h"]), int(header["w"]), header["layers"]
    bits = np.unpackbits(np.frombuffer(zlib.decompress(blob[4 + n :]), np.uint8), count=len(layers) * h * w)
    stack = bits.reshape(len(layers), h, w).astype(bool)
    values = {name: stack[k] for k, name in enumerate(layers)}
    return MapSnapshot(
        resolution_m=float(header["res"]),
        origin_xy_m=(float(header["origin"][0]), float(header["origin"][1])),
        obstacle=values["obstacle"],
        explored=values["explored"],
        visited=values["visited"],
        collision=values["collision"],
        goal=values["goal"],
        frontier=values["frontier"],
        blacklist=values.get("blacklist"),
    )


def _subsample(points: np.ndarray, n_max: int) -> np.ndarray:
    points = np.asarray(points)
    if len(points) <= n_max:
        return points
    idx = np.linspace(0, len(points) - 1, n_max).round().astype(int)
    return points[idx]


def step_extras(rec: StepRecord, config: ReplayConfig) -> dict[str, Any]:
    """The per-step JSON: candidates, goal points, plan, target (start-relative metres)."""
    r = rec.record
    if r is None:
        return {}
    candidates = [
        {
            "id": int(c.id),
            "state": str(c.state),
            "xy_m": [round(float(c.xy_m[0]), 3), round(float(c.xy_m[1]), 3)],
            "n_views": int(c.n_views),
            "best_score": round(float(c.best_score), 2),
            "distance_m": round(float(c.distance_m), 2),
            **({"why": str(c.why)} if getattr(c, "why", None) else {}),
        }
        for c in getattr(r, "candidates", ())
    ]
    goal = _subsample(np.asarray(r.goal_points_xyz, np.float32).reshape(-1, 3), config.max_goal_points)
    plan = _subsample(np.asarray(r.plan_xy_m, np.float32).reshape(-1, 2), config.max_plan_points)
    return {
        "candidates": candidates,
        "goal_points": np.round(goal, 3).tolist(),
        "plan": np.round(plan, 3).tolist(),
        "target": None if r.target_xy_m is None else [round(float(v), 3) for v in r.target_xy_m],
        "target_kind": r.target_kind,
        "explored_m2": None if r.map is None else round(float(r.map.explored.sum()) * r.map.resolution_m**2, 2),
    }


def thumbnail_jpeg(rgb: np.ndarray, config: ReplayConfig) -> bytes:
    h, w = rgb.shape[:2]
    width = min(config.thumb_width_px, w)
    height = max(1, round(h * width / w))
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgb)).resize((width, height), Image.Resampling.BILINEAR).save(
        buf, format="JPEG", quality=config.jpeg_quality
    )
    return buf.getvalue()


# --- writing ------------------------------------------------------------------------------


class ReplayRecorder:
    """Feeds a run's replay rows to the store, one step at a time (the worker thread)."""

    def __init__(self, store: RunStore, run_id: str, config: ReplayConfig = ReplayConfig()) -> None:
        self.store = store
        self.run_id = run_id
        self.config = config
        self._last: StepRecord | None = None
        self._last_map_step: int | None = None
        self._detected = False

    def add(self, rec: StepRecord) -> None:
        self._last = rec
        extras = step_extras(rec, self.config)
        self.store.add_replay_step(self.run_id, rec.step, thumbnail_jpeg(rec.rgb, self.config), json.dumps(extras))
        r = rec.record
        first_detection = r is not None and bool(r.goal_detected) and not self._detected
        self._detected = self._detected or first_detection
        if r is not None and r.map is not None and (rec.step % self.config.map_every == 0 or first_detection):
            self._store_map(rec)

    def _store_map(self, rec: StepRecord) -> None:
        assert rec.record is not None and rec.record.map is not None  # callers check: only steps with a map
        self.store.add_replay_map(self.run_id, rec.step, encode_map(rec.record.map))
        self._last_map_step = rec.step

    def finish(self) -> None:
        """The last step's map (what the agent knew when the run ended)."""
        rec = self._last
        if (
            rec is not None
            and rec.record is not None
            and rec.record.map is not None
            and self._last_map_step != rec.step
        ):
            self._store_map(rec)


# --- reading --------------------------------------------------------------------------------


def replay_marks(steps: list[dict[str, Any]], extras: Mapping[int, Mapping[str, Any]]) -> dict[str, Any]:
    """Steps worth jumping to: the first detection, each candidate's rejection, the stop."""
    first = next((s["step"] for s in steps if s.get("goal_detected")), None)
    rejected: list[dict[str, Any]] = []
    seen: set[int] = set()
    for s in steps:
        for c in extras.get(s["step"], {}).get("candidates", []):
            if c.get("state") == "rejected" and c["id"] not in seen:
                seen.add(c["id"])
                rejected.append({"step": s["step"], "candidate": c["id"]})
    stop = steps[-1]["step"] if steps and steps[-1].get("action_name") == "STOP" else None
    return {
        "first_detection": first,
        "candidate_rejected": rejected,
        "stop": stop,
        "last": steps[-1]["step"] if steps else None,
    }


@lru_cache(maxsize=64)
def _decoded(blob: bytes) -> MapSnapshot:
    return decode_map(blob)


def map_picture(
    store: RunStore, run_id: str, step: int, steps: list[dict[str, Any]], extras: dict[str, Any], size_px: int = 480
) -> np.ndarray | None:
    """The map as the agent knew it at ``step``: the latest snapshot at or before it, with the
    trajectory so far, this step's pose, plan, target and goal points drawn over it."""
    from console.pictures import render_map

    found = store.replay_map_at(run_id, step)
    snapshot = _decoded(found[1]) if found is not None else None
    upto = [s for s in steps if s["step"] <= step]
    if not upto:
        return None
    me = upto[-1]
    traj = np.array([[s["x_m"], s["y_m"]] for s in upto], np.float64)
    goal = np.asarray(extras.get("goal_points") or np.zeros((0, 3)), np.float64).reshape(-1, 3)
    plan = np.asarray(extras.get("plan") or np.zeros((0, 2)), np.float64).reshape(-1, 2)
    cand = [c["xy_m"] for c in extras.get("candidates", []) if c.get("state") != "rejected"]
    target = extras.get("target")
    rgb, _ = render_map(
        snapshot,
        trajectory_xy_m=traj,
        pose=Pose2D(me["x_m"], me["y_m"], me["yaw_rad"] if me["yaw_rad"] is not None else 0.0),
        plan_xy_m=plan,
        target_xy_m=None if target is None else (float(target[0]), float(target[1])),
        goal_points_xyz=goal,
        extra_points_xy_m=np.asarray(cand, np.float64).reshape(-1, 2) if cand else None,
        size_px=size_px,
    )
    return rgb
