"""Per-run files under ``<data>/runs/<run id>/``.

goal.png            the goal photo as given to the agent (upright RGB)
goal_upload.<ext>   the uploaded bytes (extension from the detected format, never the client's name)
trajectory.json     per-step pose, action, mode, reason, re-ID score, target
map.png             the final map with trajectory, goal points and target
run.webp            animated: egocentric view beside the map, one frame per step (decimated)

Names are fixed here; the API serves only these names, so no request can reach
another path. Frames are kept as JPEG bytes in memory (about 10 kB each) and
halved in number whenever they exceed ``max_frames``, so memory stays bounded on
a 1000-step run.
"""

from __future__ import annotations

import io
import json
import logging
import re
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from console.jsonio import json_safe
from console.pictures import render_map, video_frame
from console.replay import ReplayRecorder
from console.session import StepRecord

logger = logging.getLogger(__name__)

ARTIFACT_NAMES: dict[str, str] = {
    "goal.png": "image/png",
    "goal_upload.jpg": "image/jpeg",
    "goal_upload.png": "image/png",
    "goal_upload.webp": "image/webp",
    "goal_upload.heic": "image/heic",
    "trajectory.json": "application/json",
    "map.png": "image/png",
    "run.webp": "image/webp",
}

_RUN_ID = re.compile(r"[0-9a-f]{12}")


def valid_run_id(run_id: str) -> bool:
    return bool(_RUN_ID.fullmatch(run_id))  # fullmatch: "$" would let a trailing newline through


def run_dir(data_dir: Path, run_id: str) -> Path:
    if not valid_run_id(run_id):
        raise ValueError(f"not a run id: {run_id!r}")
    return Path(data_dir) / "runs" / run_id


def existing_artifacts(data_dir: Path, run_id: str) -> list[str]:
    d = run_dir(data_dir, run_id)
    return [name for name in ARTIFACT_NAMES if (d / name).is_file()]


class ArtifactWriter:
    """Collects a run's frames and writes its files. Used only by the worker thread."""

    def __init__(
        self, directory: Path, max_frames: int = 300, frame_height_px: int = 240, replay: ReplayRecorder | None = None
    ) -> None:
        self.replay = replay  # the run's replay rows in the store (console.replay), fed step by step
        self.dir = Path(directory)
        self.dir.mkdir(parents=True, exist_ok=True)
        self.max_frames = max_frames
        self.frame_height_px = frame_height_px
        self._frames: list[bytes] = []
        self._stride = 1  # keep every ``_stride``-th step once decimated
        self._last: StepRecord | None = None
        self._goal_png: Callable[[], bytes] | None = None

    def write_goal(self, png_bytes: Callable[[], bytes], upload: bytes, extension: str) -> None:
        """The uploaded bytes now; goal.png (the photo as the agent sees it, ``png_bytes()``) at
        ``flush_goal``: the first action does not need the file and encoding it takes 25-70 ms
        (a 512 px to 1024 px photo), so the run's worker writes it right after the first action."""
        name = f"goal_upload.{extension}"
        if name not in ARTIFACT_NAMES:
            raise ValueError(f"unexpected upload extension {extension!r}")
        (self.dir / name).write_bytes(upload)
        self._goal_png = png_bytes

    def flush_goal(self) -> None:
        """Write goal.png unless written already (after the first action, or at ``finish``)."""
        if self._goal_png is not None:
            png_bytes, self._goal_png = self._goal_png, None
            (self.dir / "goal.png").write_bytes(png_bytes())

    def add_replay(self, rec: StepRecord) -> None:
        """Store the step's replay row (pictures, extras). Called before the step is announced, so a
        client that hears of step N can load its pictures."""
        if self.replay is not None:
            try:
                self.replay.add(rec)
            except Exception:  # the replay is a record of the run, never a reason to end it
                logger.exception("replay: step %d of run %s not recorded", rec.step, self.replay.run_id)

    def add_step(self, rec: StepRecord) -> None:
        """The step's video frame (every ``stride``-th step); the replay row is ``add_replay``'s."""
        self._last = rec
        if rec.step % self._stride:
            return
        map_rgb, _ = self._map(rec, size_px=self.frame_height_px)
        r = rec.record
        score = "" if r is None or r.reid_score is None else f" score {r.reid_score:.1f}"
        caption = f"step {rec.step} {rec.action.name} {'' if r is None else r.mode}{score}"
        frame = video_frame(rec.rgb, map_rgb, caption, self.frame_height_px)
        buf = io.BytesIO()
        Image.fromarray(frame).save(buf, format="JPEG", quality=80)
        self._frames.append(buf.getvalue())
        if len(self._frames) > self.max_frames:
            self._frames = self._frames[::2]
            self._stride *= 2

    @staticmethod
    def _map(rec: StepRecord, size_px: int) -> tuple[np.ndarray, Any]:
        r = rec.record
        return render_map(
            r.map if r is not None else None,
            trajectory_xy_m=rec.trajectory_xy_m,
            pose=rec.pose,
            plan_xy_m=None if r is None else r.plan_xy_m,
            target_xy_m=None if r is None else r.target_xy_m,
            goal_points_xyz=None if r is None else r.goal_points_xyz,
            size_px=size_px,
        )

    def finish(self, trajectory: Iterable[Mapping[str, Any]], summary: Mapping[str, Any]) -> list[str]:
        """Write trajectory.json, map.png and run.webp (and goal.png if no step wrote it);
        returns the names written."""
        written = []
        self.flush_goal()
        if self.replay is not None:
            self.replay.finish()
        doc = {"summary": json_safe(dict(summary)), "steps": json_safe(list(trajectory))}
        (self.dir / "trajectory.json").write_text(json.dumps(doc, indent=1, allow_nan=False))
        written.append("trajectory.json")
        if self._last is not None:
            map_rgb, _ = self._map(self._last, size_px=720)
            Image.fromarray(map_rgb).save(self.dir / "map.png")
            written.append("map.png")
        if self._frames:
            frames = [Image.open(io.BytesIO(b)).convert("RGB") for b in self._frames]
            duration_ms = max(80, int(200 * self._stride**0.5))
            frames[0].save(
                self.dir / "run.webp",
                format="WEBP",
                save_all=True,
                append_images=frames[1:],
                duration=duration_ms,
                loop=0,
                quality=70,
                method=0,  # fastest encoder setting: this runs at the end of every run
            )
            written.append("run.webp")
        self._frames = []
        return written
