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

A bad photo set silently degrades the robot (issue 33: the same file twice for each of two
objects proposed tau 936 at "F 1.0"), so the set is checked before any pair is scored and the
proposal before it is saved:

* refused at upload (HTTP 422, ``check_photo_set``): the same file twice, or the same picture
  twice (re-encoded or resized: ``near_identical``), anywhere in the set; fewer than
  ``MIN_VIEWS_PER_OBJECT`` photos of an object; fewer than ``MIN_SAME_PAIRS`` same-object or
  ``MIN_DIFFERENT_PAIRS`` different-object pairs (an F from a handful of pairs is luck);
* refused at saving (HTTP 409, ``proposal_problems``): a tau outside ``TAU_BAND`` times the
  packaged calibration's tau for the same matcher and score (see ``TAU_BAND``).

Saving keeps what it replaced (``<deployment>.history.json``: a stack of the documents in force
before each save, ``null`` for the packaged calibration); ``Calibrator.undo`` puts the last one
back.
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
MIN_VIEWS_PER_OBJECT = 3  # distinct photos of each object (near-identical ones are refused)
# Pairs behind the F: with fewer than 9 same-object pairs one pair moves recall by more than 10
# points. 3 objects x 3 photos (9 same, 27 different) or 2 x 4 (12, 16) pass; 2 x 3 (6) does not.
MIN_SAME_PAIRS = 9
MIN_DIFFERENT_PAIRS = 9
MAX_PHOTOS = 40  # 780 pairs: about 80 s of matching with XFeat + LighterGlue on 2 cores
CURVE_POINTS = 200  # curves are thinned to this many points for the page
DEPLOYMENTS = ("sim", "stretch")
# Two photos are the same picture when their difference hashes differ in at most this many of
# 64 bits, or their 32 x 32 grey thumbnails by at most this mean difference (of 255). Measured
# on simulator goal images (4 views of each of 8 objects of home 0): distinct views of one
# object differ by at least 9 bits and 7.4 grey levels; a JPEG re-encoded at quality 60 after a
# resize by 0 bits and 0.4 levels.
NEAR_IDENTICAL_BITS = 5
NEAR_IDENTICAL_GREY = 3.0
# The tau a deployment may save, as factors of the packaged (simulator) tau of the same matcher
# and score: 75.3 -> 9.4 to 301 for XFeat + LighterGlue's conf score. A camera and a home change
# tau, but by a factor of a few: the reference implementation went from 24.5 in simulation to 6.0
# on the robot (x 0.245); the band allows twice that change downwards (x 1/8) and a change of
# the same size upwards (x 4). A tau beyond it does not come from real views of objects (issue
# 33's 936 came from the same file matched with itself: every keypoint matches). Small sets land
# low: 3 objects x 3 simulator views gave 13.4 (x 0.18) with this matcher, inside the band; the
# median different-object pair there scored 3.1, so a tau much below the band accepts about any
# pair of different objects.
TAU_BAND = (1 / 8, 4.0)


class CalibrationInputError(ValueError):
    """The photo set cannot calibrate anything (HTTP 422), or a proposal cannot be saved."""

    def __init__(self, message: str, code: str = "too_few_photos") -> None:
        super().__init__(message)
        self.code = code


@dataclass(frozen=True, slots=True)
class LabelledPhoto:
    object_label: str
    filename: str
    photo: GoalPhoto


def _grey_thumb(rgb: np.ndarray) -> np.ndarray:
    from PIL import Image

    small = Image.fromarray(np.asarray(rgb, dtype=np.uint8)).convert("L").resize((32, 32), Image.Resampling.BOX)
    return np.asarray(small, dtype=np.float32)


def _same_picture(a: LabelledPhoto, b: LabelledPhoto, thumbs: dict[int, np.ndarray]) -> str | None:
    """Why ``a`` and ``b`` are one picture (the same file, the same pixels, or near-identical), or None."""
    from console.photos import hamming

    if a.photo.sha256 == b.photo.sha256:
        return "the same file"
    if a.photo.rgb.shape == b.photo.rgb.shape and np.array_equal(a.photo.rgb, b.photo.rgb):
        return "the same pixels"
    bits = hamming(a.photo.dhash, b.photo.dhash)
    grey = float(np.abs(thumbs[id(a)] - thumbs[id(b)]).mean())
    if bits <= NEAR_IDENTICAL_BITS or grey <= NEAR_IDENTICAL_GREY:
        return f"near-identical ({bits} of 64 hash bits differ, mean grey difference {grey:.1f})"
    return None


def check_photo_set(photos: Sequence[LabelledPhoto]) -> dict[str, int]:
    """Photos per object; raises ``CalibrationInputError`` (with a ``code``) naming what is wrong."""
    per_object: dict[str, int] = {}
    for p in photos:
        per_object[p.object_label] = per_object.get(p.object_label, 0) + 1
    if len(photos) > MAX_PHOTOS:
        raise CalibrationInputError(
            f"{len(photos)} photos: at most {MAX_PHOTOS} per calibration (pairs grow with the square)",
            "too_many_photos",
        )
    thumbs = {id(p): _grey_thumb(p.photo.rgb) for p in photos}
    for i, a in enumerate(photos):
        for b in photos[i + 1 :]:
            why = _same_picture(a, b, thumbs)
            if why is None:
                continue
            where = (
                f"both of {a.object_label}"
                if a.object_label == b.object_label
                else f"one labelled {a.object_label}, the other {b.object_label}"
            )
            raise CalibrationInputError(
                f"{a.filename} and {b.filename} are one picture ({why}; {where}): a repeated photo is no new view "
                "and makes the threshold worthless; remove one and photograph the object from another side or "
                "distance",
                "duplicate_photos",
            )
    if len(per_object) < MIN_OBJECTS:
        raise CalibrationInputError(
            f"photos of {len(per_object)} object(s): photograph at least {MIN_OBJECTS} different objects, "
            "so that there are pairs of different objects to tell apart"
        )
    few = sorted(label for label, n in per_object.items() if n < MIN_VIEWS_PER_OBJECT)
    if few:
        raise CalibrationInputError(
            f"objects with fewer than {MIN_VIEWS_PER_OBJECT} photos: "
            f"{', '.join(f'{label} ({per_object[label]})' for label in few)}; take each object "
            "from a few sides and distances"
        )
    same = sum(n * (n - 1) // 2 for n in per_object.values())
    different = len(photos) * (len(photos) - 1) // 2 - same
    if same < MIN_SAME_PAIRS or different < MIN_DIFFERENT_PAIRS:
        raise CalibrationInputError(
            f"{same} same-object and {different} different-object pairs: a threshold needs at least "
            f"{MIN_SAME_PAIRS} and {MIN_DIFFERENT_PAIRS} (an F from fewer is luck); add an object or more "
            "photos of each (3 objects x 3 photos, or 2 x 4)",
            "too_few_pairs",
        )
    return per_object


def packaged_tau(matcher: str, score: str) -> float | None:
    """The packaged (simulator) calibration's tau for a matcher and score; None without one."""
    from agent.reid.identifier import calibration_path

    path = calibration_path(matcher, score)
    try:
        tau = float(json.loads(path.read_text())["tau"])
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return tau if np.isfinite(tau) and tau > 0 else None


def proposal_problems(tau: float, matcher: str, score: str) -> tuple[list[dict[str, str]], dict[str, Any]]:
    """Why a proposed tau must not be saved (empty: it may), and the band it was held to."""
    reference = packaged_tau(matcher, score)
    band: dict[str, Any] = {"packaged_tau": reference, "low": None, "high": None}
    problems: list[dict[str, str]] = []
    if not np.isfinite(tau) or tau <= 0:
        problems.append({"code": "bad_tau", "message": f"tau {tau} is not a positive number"})
        return problems, band
    if reference is None:  # no packaged calibration of this matcher: nothing to compare with
        return problems, band
    low, high = reference * TAU_BAND[0], reference * TAU_BAND[1]
    band.update(low=low, high=high)
    if not low <= tau <= high:
        side = "above" if tau > high else "below"
        problems.append(
            {
                "code": "implausible_tau",
                "message": (
                    f"tau {tau:.1f} is far {side} what {matcher} ({score} score) gives on real views: the packaged "
                    f"calibration's tau is {reference:.1f}, and a camera or home moves it within {low:.1f} to "
                    f"{high:.1f}. Photos that are nearly the same picture, or objects that look alike, give such "
                    "a tau: photograph each object from clearly different sides and distances"
                ),
            }
        )
    return problems, band


def calibration_file(data_dir: Path, deployment: str) -> Path:
    if deployment not in DEPLOYMENTS:
        raise ValueError(f"unknown deployment {deployment!r}")
    return Path(data_dir) / "calibration" / f"{deployment}.json"


def history_file(data_dir: Path, deployment: str) -> Path:
    """What each save replaced, oldest first: ``[{"replaced": time, "previous": doc or null}]``."""
    return calibration_file(data_dir, deployment).with_suffix(".history.json")


def _read_history(data_dir: Path, deployment: str) -> list[dict[str, Any]]:
    path = history_file(data_dir, deployment)
    if not path.is_file():
        return []
    try:
        entries = json.loads(path.read_text())
    except ValueError:
        logger.warning("calibration history %s cannot be read; undo starts afresh", path)
        return []
    return [e for e in entries if isinstance(e, dict)] if isinstance(entries, list) else []


def _write_json(path: Path, doc: Any) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(doc, indent=1) + "\n")
    tmp.replace(path)


def _saved_view(doc: dict[str, Any], name: str) -> dict[str, Any]:
    return {
        "tau": doc.get("tau"),
        "matcher": doc.get("matcher"),
        "score": doc.get("score"),
        "source": f"your photos ({name}, {doc.get('created', '')})",
    }


def _packaged_in_force(deployment: str) -> dict[str, Any]:
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
    return {"tau": resolve_tau(reid), "matcher": reid.matcher, "score": reid.score, "source": where}


def tau_in_force(data_dir: Path, deployment: str) -> dict[str, Any]:
    """Which tau the deployment uses now and where it comes from; ``undo``: what undoing the
    last save would put back (None: nothing saved from this console to undo)."""
    saved = calibration_file(data_dir, deployment)
    history = _read_history(data_dir, deployment)
    undo = None
    if history:
        previous = history[-1].get("previous")
        undo = _saved_view(previous, saved.name) if isinstance(previous, dict) else _packaged_in_force(deployment)
    if saved.is_file():
        doc = json.loads(saved.read_text())
        return {**_saved_view(doc, saved.name), "file": str(saved), "saved": doc, "undo": undo}
    return {**_packaged_in_force(deployment), "file": None, "saved": None, "undo": undo}


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
            "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(self.created_s)),
        }

    def summary(self) -> dict[str, Any]:
        """The view without the curves and pair scores (for the list of jobs)."""
        out = self.view()
        result = out.pop("result")
        out["savable"] = None if result is None else result["checks"]["savable"]
        return out


class Calibrator:
    """Runs calibration jobs on a thread, one at a time; keeps the recent ones."""

    def __init__(self, data_dir: Path, matcher_for: Any | None = None) -> None:
        """``matcher_for(deployment) -> (matcher, reid_config)``; default: the agent's shared matcher."""
        self.data_dir = Path(data_dir)
        self._matcher_for = matcher_for or _deployment_matcher
        self._lock = threading.Lock()
        self._files_lock = threading.Lock()  # saves and undos of the calibration files
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

    def jobs(self) -> list[CalibrationJob]:
        """The recent jobs, newest first (a page reloaded mid-job finds its job here)."""
        with self._lock:
            return sorted(self._jobs.values(), key=lambda j: j.created_s, reverse=True)

    def wait(self, timeout_s: float) -> None:
        with self._lock:
            thread = self._thread
        if thread is not None:
            thread.join(timeout_s)

    def save(self, job: CalibrationJob) -> dict[str, Any]:
        """Put the job's tau in force for its deployment; refuses a proposal with problems.
        Returns the saved document and what it replaced (``previous``: the tau in force before)."""
        if job.state != "done" or job.result is None:
            raise CalibrationInputError(f"calibration {job.id} has no result to save ({job.state})", "not_done")
        proposal = job.result["proposal"]
        problems, _ = proposal_problems(proposal["tau"], proposal["matcher"], proposal["score"])
        if problems:
            raise CalibrationInputError("not saved: " + "; ".join(p["message"] for p in problems), problems[0]["code"])
        doc = {
            "matcher": proposal["matcher"],
            "score": proposal["score"],
            "tau": proposal["tau"],
            "max_f": proposal["max_f"],
            "precision": proposal["precision"],
            "recall": proposal["recall"],
            "same_pairs": job.result["same_pairs"],
            "different_pairs": job.result["different_pairs"],
            "same_pairs_accepted": proposal["same_pairs_accepted"],
            "different_pairs_accepted": proposal["different_pairs_accepted"],
            "objects": job.result["objects"],
            "photos": job.result["photos"],
            "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "source": f"operator photos, console calibration {job.id}",
        }
        path = calibration_file(self.data_dir, job.deployment)
        with self._files_lock:
            previous = tau_in_force(self.data_dir, job.deployment)
            history = _read_history(self.data_dir, job.deployment)
            history.append({"replaced": doc["created"], "by": job.id, "previous": previous["saved"]})
            _write_json(history_file(self.data_dir, job.deployment), history[-20:])
            _write_json(path, doc)
        logger.info(
            "calibration %s saved for %s: tau %.4g (was %.4g from %s)",
            job.id,
            job.deployment,
            doc["tau"],
            previous["tau"],
            previous["source"],
        )
        previous.pop("undo", None)
        return {"saved": doc, "previous": previous}

    def undo(self, deployment: str) -> dict[str, Any]:
        """Put back what the last save replaced: the previous file, or the packaged calibration.
        Returns ``undone`` (the document taken out of force)."""
        path = calibration_file(self.data_dir, deployment)
        with self._files_lock:
            history = _read_history(self.data_dir, deployment)
            if not history:
                raise CalibrationInputError(f"no saved calibration of {deployment} to undo", "nothing_to_undo")
            entry = history.pop()
            undone = json.loads(path.read_text()) if path.is_file() else None
            previous = entry.get("previous")
            if isinstance(previous, dict):
                _write_json(path, previous)
            else:
                path.unlink(missing_ok=True)
            _write_json(history_file(self.data_dir, deployment), history)
        logger.info(
            "calibration of %s undone: %s back in force",
            deployment,
            "the previous file" if previous else "the packaged tau",
        )
        return {"undone": undone}

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
        problems, band = proposal_problems(chosen["tau"], reid.matcher, reid.score)
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
            # what saving would do: refused with these problems, else allowed
            "checks": {"savable": not problems, "problems": problems, "tau_band": band},
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
                    "accepted": bool(accepted[k]),
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
