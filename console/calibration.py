"""A deployment's re-ID threshold tau from the operator's own photos.

The threshold does not transfer between cameras and homes (docs/architecture.md section 5). The paper
chooses tau by the maximal F-measure over goal-image pairs (same instance vs different
instance); here the pairs are the operator's photos: several photos of each of a few
objects of their own home, grouped by object. Every pair is scored with the deployment's
matcher (the one the agent uses), the precision-recall and F curves are computed
(``sim.evaluation.calibration_core.pr_curves``, the same code as ``imgnav calibrate``), and
the maximal-F tau is proposed. Saving writes ``<data>/calibration/<deployment>.json``:

    {"matcher", "score", "tau", "max_f", "precision", "recall", "same_pairs",
     "different_pairs", "objects", "photos", "created", "source"}

which the deployment's agent reads (``console.agents.resolve_deployment_tau``: the stretch
deployment uses it when present); until then the packaged calibration is in force. One job at a time, never during a run (they share the
matcher, and the robot's run should not slow down).
"""

from __future__ import annotations

import json
import logging
import threading
import time
import uuid
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from console.photos import GoalPhoto

logger = logging.getLogger(__name__)

MIN_OBJECTS = 2
MIN_PHOTOS_PER_OBJECT = 2
MAX_PHOTOS = 40  # 780 pairs: about 80 s of matching with XFeat + LighterGlue on 2 cores
CURVE_POINTS = 200  # curves are thinned to this many points for the page
DEPLOYMENTS = ("sim", "stretch")


class CalibrationInputError(ValueError):
    """The photo set cannot calibrate anything (HTTP 422)."""


@dataclass(frozen=True, slots=True)
class LabelledPhoto:
    object_label: str
    filename: str
    photo: GoalPhoto


def check_photo_set(photos: Sequence[LabelledPhoto]) -> dict[str, int]:
    """Photos per object; raises ``CalibrationInputError`` with what is missing."""
    per_object: dict[str, int] = {}
    for p in photos:
        per_object[p.object_label] = per_object.get(p.object_label, 0) + 1
    if len(photos) > MAX_PHOTOS:
        raise CalibrationInputError(
            f"{len(photos)} photos: at most {MAX_PHOTOS} per calibration (pairs grow with the square)"
        )
    if len(per_object) < MIN_OBJECTS:
        raise CalibrationInputError(
            f"photos of {len(per_object)} object(s): photograph at least {MIN_OBJECTS} different objects, "
            "so that there are pairs of different objects to tell apart"
        )
    few = sorted(label for label, n in per_object.items() if n < MIN_PHOTOS_PER_OBJECT)
    if few:
        raise CalibrationInputError(
            f"objects with fewer than {MIN_PHOTOS_PER_OBJECT} photos: {', '.join(few)}; take each object "
            "from a few sides and distances"
        )
    return per_object


def calibration_file(data_dir: Path, deployment: str) -> Path:
    if deployment not in DEPLOYMENTS:
        raise ValueError(f"unknown deployment {deployment!r}")
    return Path(data_dir) / "calibration" / f"{deployment}.json"


def tau_in_force(data_dir: Path, deployment: str) -> dict[str, Any]:
    """Which tau the deployment uses now and where it comes from."""
    saved = calibration_file(data_dir, deployment)
    if saved.is_file():
        doc = json.loads(saved.read_text())
        return {
            "tau": doc.get("tau"),
            "matcher": doc.get("matcher"),
            "score": doc.get("score"),
            "source": f"your photos ({saved.name}, {doc.get('created', '')})",
            "file": str(saved),
            "saved": doc,
        }
    from agent.config import load_agent_config
    from agent.reid.identifier import calibration_path, resolve_tau

    reid = load_agent_config(deployment).reid
    where = (
        "the deployment config"
        if reid.tau is not None
        else (
            reid.calibration_file
            or f"the packaged simulator calibration ({calibration_path(reid.matcher, reid.score).name})"
        )
    )
    return {
        "tau": resolve_tau(reid),
        "matcher": reid.matcher,
        "score": reid.score,
        "source": where,
        "file": None,
        "saved": None,
    }


@dataclass
class CalibrationJob:
    id: str
    deployment: str
    photos: list[LabelledPhoto]
    state: str = "queued"  # queued | extracting | matching | done | failed
    progress: float = 0.0
    message: str = ""
    result: dict[str, Any] | None = None
    error: str | None = None
    created_s: float = field(default_factory=time.time)
    seconds: float | None = None

    def view(self) -> dict[str, Any]:
        per_object: dict[str, int] = {}
        for p in self.photos:
            per_object[p.object_label] = per_object.get(p.object_label, 0) + 1
        return {
            "id": self.id,
            "deployment": self.deployment,
            "state": self.state,
            "progress": round(self.progress, 3),
            "message": self.message,
            "objects": per_object,
            "photos": len(self.photos),
            "result": self.result,
            "error": self.error,
            "seconds": self.seconds,
        }


class Calibrator:
    """Runs calibration jobs on a thread, one at a time; keeps the recent ones."""

    def __init__(self, data_dir: Path, matcher_for: Any | None = None) -> None:
        """``matcher_for(deployment) -> (matcher, reid_config)``; default: the agent's shared matcher."""
        self.data_dir = Path(data_dir)
        self._matcher_for = matcher_for or _deployment_matcher
        self._lock = threading.Lock()
        self._jobs: dict[str, CalibrationJob] = {}
        self._thread: threading.Thread | None = None

    @property
    def busy(self) -> bool:
        with self._lock:
            return self._thread is not None and self._thread.is_alive()

    def start(self, deployment: str, photos: list[LabelledPhoto]) -> CalibrationJob:
        if deployment not in DEPLOYMENTS:
            raise CalibrationInputError(f"no deployment {deployment!r}; deployments are {list(DEPLOYMENTS)}")
        check_photo_set(photos)
        job = CalibrationJob(uuid.uuid4().hex[:12], deployment, photos)
        with self._lock:
            if self._thread is not None and self._thread.is_alive():
                raise RuntimeError("a calibration is already running")
            self._jobs[job.id] = job
            while len(self._jobs) > 10:
                self._jobs.pop(next(iter(self._jobs)))
            self._thread = threading.Thread(target=self._run, args=(job,), name=f"calibration-{job.id}", daemon=True)
            self._thread.start()
        return job

    def get(self, job_id: str) -> CalibrationJob | None:
        with self._lock:
            return self._jobs.get(job_id)

    def wait(self, timeout_s: float) -> None:
        with self._lock:
            thread = self._thread
        if thread is not None:
            thread.join(timeout_s)

    def save(self, job: CalibrationJob) -> dict[str, Any]:
        if job.state != "done" or job.result is None:
            raise CalibrationInputError(f"calibration {job.id} has no result to save ({job.state})")
        proposal = job.result["proposal"]
        doc = {
            "matcher": proposal["matcher"],
            "score": proposal["score"],
            "tau": proposal["tau"],
            "max_f": proposal["max_f"],
            "precision": proposal["precision"],
            "recall": proposal["recall"],
            "same_pairs": job.result["same_pairs"],
            "different_pairs": job.result["different_pairs"],
            "objects": job.result["objects"],
            "photos": job.result["photos"],
            "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "source": f"operator photos, console calibration {job.id}",
        }
        path = calibration_file(self.data_dir, job.deployment)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps(doc, indent=1) + "\n")
        tmp.replace(path)
        logger.info("calibration %s saved for %s: tau %.4g (%s)", job.id, job.deployment, doc["tau"], path)
        return doc

    def _run(self, job: CalibrationJob) -> None:
        t0 = time.perf_counter()
        try:
            job.result = self._calibrate(job)
            job.state, job.progress = "done", 1.0
            job.message = "done"
        except Exception as exc:  # the job fails, the console lives on; the page shows why
            logger.exception("calibration %s failed", job.id)
            job.state, job.error = "failed", f"{type(exc).__name__}: {exc}"
        job.seconds = time.perf_counter() - t0

    def _calibrate(self, job: CalibrationJob) -> dict[str, Any]:
        from sim.evaluation.calibration_core import pr_curves

        matcher, reid = self._matcher_for(job.deployment)
        n = len(job.photos)
        job.state, job.message = "extracting", f"keypoints of {n} photos"
        t0 = time.perf_counter()
        feats = []
        for k, p in enumerate(job.photos):
            feats.append(matcher.extract(p.photo.rgb, reid.goal_max_keypoints))
            job.progress = 0.2 * (k + 1) / n
        extract_s = time.perf_counter() - t0
        pairs = [(a, b) for a in range(n) for b in range(a + 1, n)]
        label = np.array([job.photos[a].object_label == job.photos[b].object_label for a, b in pairs], bool)
        conf = np.zeros(len(pairs))
        count = np.zeros(len(pairs))
        job.state = "matching"
        t0 = time.perf_counter()
        for k, (a, b) in enumerate(pairs):
            m = matcher.match(feats[a], feats[b])
            conf[k] = float(np.sum(m.confidence, dtype=np.float64))
            count[k] = float(len(m))
            job.progress = 0.2 + 0.8 * (k + 1) / len(pairs)
            job.message = f"pair {k + 1} of {len(pairs)}"
        match_s = time.perf_counter() - t0
        curves = {}
        for kind, scores in (("conf", conf), ("count", count)):
            c = pr_curves(scores, label)
            keep = np.unique(
                np.linspace(0, len(c.threshold) - 1, min(CURVE_POINTS, len(c.threshold))).round().astype(int)
            )
            curves[kind] = {
                "tau": c.tau,
                "max_f": c.max_f,
                "precision": float(c.precision[c.best]),
                "recall": float(c.recall[c.best]),
                "threshold": c.threshold[keep].tolist(),
                "precision_curve": c.precision[keep].tolist(),
                "recall_curve": c.recall[keep].tolist(),
                "f_curve": c.f[keep].tolist(),
            }
        chosen = curves[reid.score]
        # How many pairs support the proposal: the same-object pairs it accepts, the
        # different-object pairs it (wrongly) accepts, out of how many of each.
        scores = conf if reid.score == "conf" else count
        accepted = scores >= chosen["tau"]
        objects: dict[str, int] = {}
        for p in job.photos:
            objects[p.object_label] = objects.get(p.object_label, 0) + 1
        return {
            "proposal": {
                "matcher": reid.matcher,
                "score": reid.score,
                "tau": chosen["tau"],
                "max_f": chosen["max_f"],
                "precision": chosen["precision"],
                "recall": chosen["recall"],
                "same_pairs_accepted": int((accepted & label).sum()),
                "different_pairs_accepted": int((accepted & ~label).sum()),
            },
            "curves": curves,
            "same_pairs": int(label.sum()),
            "different_pairs": int((~label).sum()),
            "objects": objects,
            "photos": n,
            "pair_scores": [
                {
                    "a": job.photos[a].filename,
                    "b": job.photos[b].filename,
                    "same": bool(label[k]),
                    "conf": conf[k],
                    "count": count[k],
                }
                for k, (a, b) in enumerate(pairs)
            ],
            "extract_ms_per_photo": 1000 * extract_s / n,
            "match_ms_per_pair": 1000 * match_s / max(len(pairs), 1),
        }


def _deployment_matcher(deployment: str) -> tuple[Any, Any]:
    from agent.config import load_agent_config
    from console.agents import shared_matcher

    reid = load_agent_config(deployment).reid
    return shared_matcher(reid), reid
