"""The agent's memory of a home across goals (issue 31; docs/architecture.md section 11).

A home robot is asked for one object after another in the same home. ``HomeMemory`` is what the
Mod-IIN agent carries from one goal to the next:

* the map (``agent.mapping.GridMap``): its geometry, i.e. obstacles, the visited area and
  collision marks, which plan every later goal's paths. What a search made belongs to the goal
  that made it and is cleared when the next goal begins: the goal layer and the two candidate
  blacklists (a candidate rejected for the couch says nothing about the plant) and the given-up
  frontiers. The explored area is carried over: a goal the keyframes did not recall is most
  likely where no earlier goal looked, so its exploration starts at the edge of what was looked
  over. But a room looked over for the couch was not looked over for the plant (the keyframes
  keep one view per place and heading, and a far view may not score): when no frontier is left,
  the agent forgets the carried area once and explores again (``ModIINAgent``, at its first
  rescan). Carried over without that, it left later goals with no frontier from their first step:
  they stopped as exhausted after a few dozen steps (3 of the first 12 later goals on valseq30);
  cleared at every goal, later goals not recalled went as from nothing, or longer
  (docs/experiments/memory.md). A goal the keyframes recall is reached without exploring either way;
* keyframes: frames seen while searching, whatever the goal was, each kept as its keypoints,
  descriptors (float16), image size, the pose it was taken from, and each keypoint's 3D point in
  the run frame, lifted from that frame's depth exactly as the localiser lifts a live match
  (``GoalLocaliser.keypoint_points``). A later goal is matched against them and localised from
  them without the image. Bounded: one keyframe per place and heading (``cell_m`` square cells,
  ``heading_bins`` bins of heading; the newest wins: it shows the home as it was last seen, from
  the latest pose), at most ``max_keyframes`` (the oldest go first) and none older than
  ``max_age_goals`` goals;
* each earlier goal's summary: its steps, final mode and event, and its final candidates
  (position, state, best score), for the record and the console.

**The frame.** Poses and points are in the run frame of ``Observation.pose``. The memory assumes
that the poses of consecutive goals are in one frame: the odometry frame of the first goal's
start, carried on, never reset between goals. A backend whose poses start again at each goal (the
simulator's, one backend per goal) must be put back in that frame: ``InHomeFrame(backend,
origin)``, with ``origin`` the pose of this goal's start in the first goal's frame; for goal k,
``origin_k = origin_(k-1).compose(end_(k-1))``, ``end_(k-1)`` being the pose (as the agent
believed it) at which goal k-1 ended, in goal k-1's own frame (``origin_0`` the identity). The
agent's records are then in the first goal's frame too. Where the frame is truly lost (a robot
whose localisation is reset, or that is moved by hand without localisation) every remembered
point is wrong: drop the memory (``clear()`` or a new ``HomeMemory``). As a check, the first pose
of a goal is compared with the last pose of the previous one (``check_start``): a jump of more
than ``frame_check_m`` is logged as a warning.

How a goal uses it (``agent.policy.ModIINAgent``, made with ``home_memory=``): at ``reset`` the
new goal's features are scored against every keyframe with the cheap gate (the mutual-nearest
descriptor count, ``agent.reid.gate.MNNGate``), the best ``recall_keyframes`` of them with the
matcher (``recall``; stopped after its exit layer below the exit stage's threshold, as a live
searching frame is), and each keyframe scoring at least the potential-evidence threshold
adds its matches on the goal-image mask as goal points with that score, as a live frame does.
The policy then runs unchanged: candidates form from those points, a remembered detection (at
tau) is a confirmed candidate, a weaker one a potential candidate verified by approach, and the
robot explores only when the memory had nothing good enough. While searching, every step offers
its frame (the features re-identification already extracted) to the memory (``offer``).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import torch

from agent.localisation import GoalLocaliser
from agent.mapping import GridMap, MappingConfig
from agent.reid.base import Features, Matcher, ScoreKind, score
from agent.reid.gate import MNNGate
from agent.reid.identifier import ReIdentifier
from agent.types import Action, AgentRecord, Backend, CandidateInfo, Observation, Pose2D

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class MemoryConfig:
    """The memory's bounds and how a new goal is scored against it."""

    cell_m: float = 1.0  # one keyframe per place: squares of this side in the run frame ...
    heading_bins: int = 8  # ... and heading: 8 bins of 45 deg (the robot turns by 30 deg)
    max_keyframes: int = 200  # 160 kB each with 1024 XFeat keypoints: 32 MB at most
    max_age_goals: int = 8  # a keyframe serves the next this-many goals after its own
    # the full matcher scores the keyframes with the most mutual-nearest descriptor pairs with the
    # goal, this many of them (each costs what a live frame's full match costs)
    recall_keyframes: int = 8
    frame_check_m: float = 0.5  # a goal starting this far from where the last one ended is logged


class _Tensor:
    """A torch tensor kept as a numpy array (``_pack``), made a tensor again by ``_unpack``."""

    __slots__ = ("array", "dtype")

    def __init__(self, array: np.ndarray, dtype: torch.dtype) -> None:
        self.array = array
        self.dtype = dtype


def _pack(value: Any, descriptors: bool = False) -> Any:
    """A matcher's feature payload with its tensors as numpy arrays (float16 for descriptors,
    everything else, keypoints included, exactly as it was)."""
    if isinstance(value, torch.Tensor):
        a = value.detach().cpu().numpy()
        return _Tensor(a.astype(np.float16) if descriptors and a.dtype.kind == "f" else a.copy(), value.dtype)
    if isinstance(value, np.ndarray):
        return value.astype(np.float16) if descriptors and value.dtype.kind == "f" else value.copy()
    if isinstance(value, dict):
        return {k: _pack(v, descriptors=k == "descriptors") for k, v in value.items()}
    if isinstance(value, (tuple, list)):
        return type(value)(_pack(v) for v in value)
    return value


def _unpack(value: Any) -> Any:
    if isinstance(value, _Tensor):
        return torch.from_numpy(np.array(value.array, copy=True)).to(value.dtype)
    if isinstance(value, np.ndarray) and value.dtype == np.float16:
        return value.astype(np.float32)
    if isinstance(value, dict):
        return {k: _unpack(v) for k, v in value.items()}
    if isinstance(value, (tuple, list)):
        return type(value)(_unpack(v) for v in value)
    return value


def _nbytes(value: Any) -> int:
    if isinstance(value, _Tensor):
        return int(value.array.nbytes)
    if isinstance(value, np.ndarray):
        return int(value.nbytes)
    if isinstance(value, dict):
        return sum(_nbytes(v) for v in value.values())
    if isinstance(value, (tuple, list)):
        return sum(_nbytes(v) for v in value)
    return 0


@dataclass(frozen=True, slots=True, eq=False)
class Keyframe:
    """A remembered frame: its features without the image, and each keypoint's 3D point.

    keypoints_xy: (N, 2) float32 pixel (x, y) in the frame; points_xyz: (N, 3) float32 run frame,
    metres, NaN rows where the keypoint has no point (no valid depth, on the floor); descriptors:
    the matcher's, packed (float16); extra: the matcher's payload, packed.
    """

    id: int  # in order of arrival in this memory, from 0
    goal_index: int  # the goal being searched for when it was seen
    step: int
    pose: Pose2D
    matcher: str
    keypoints_xy: np.ndarray
    descriptors: Any
    image_size_wh: tuple[int, int]
    points_xyz: np.ndarray
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def frame_id(self) -> int:
        """The view id its goal points get in the localiser: negative, apart from every step."""
        return -(self.id + 1)

    @property
    def nbytes(self) -> int:
        return (
            int(self.keypoints_xy.nbytes)
            + int(self.points_xyz.nbytes)
            + _nbytes(self.descriptors)
            + _nbytes(self.extra)
        )

    def features(self) -> Features:
        """The frame's features as the matcher made them (descriptors back from float16)."""
        return Features(self.keypoints_xy, _unpack(self.descriptors), self.image_size_wh, _unpack(self.extra))


@dataclass(frozen=True, slots=True, eq=False)
class Recollection:
    """A keyframe the new goal matched: its score, and per match the goal-image pixel (M, 2) and
    the keyframe's stored 3D point of its partner (M, 3) (NaN rows: none)."""

    keyframe: Keyframe
    gate_score: float
    score: float
    goal_xy: np.ndarray
    points_xyz: np.ndarray

    def goal_points(self, goal_mask: np.ndarray) -> np.ndarray:
        """(K, 3) float32: the points of the matches whose goal keypoint lies in ``goal_mask``
        (h, w) bool, as ``GoalLocaliser.add_matches`` selects a live frame's."""
        if len(self.goal_xy) == 0:
            return np.zeros((0, 3), np.float32)
        h, w = goal_mask.shape
        gx = np.clip(np.round(self.goal_xy[:, 0]).astype(int), 0, w - 1)
        gy = np.clip(np.round(self.goal_xy[:, 1]).astype(int), 0, h - 1)
        pts = self.points_xyz[goal_mask[gy, gx]]
        return pts[np.isfinite(pts).all(axis=1)]


@dataclass(frozen=True, slots=True, eq=False)
class Recall:
    """A new goal scored against the memory: how many keyframes there were, how many the gate
    passed, which the full matcher scored (keyframe id, gate score, score) and those that reached
    ``min_score``."""

    keyframes: int
    gated: int
    scored: tuple[tuple[int, float, float], ...]
    recollections: tuple[Recollection, ...]
    gate_ms: float
    match_ms: float

    @property
    def best_score(self) -> float | None:
        return max((s for _, _, s in self.scored), default=None)


@dataclass(frozen=True, slots=True)
class GoalSummary:
    """One goal in this home: its steps, how it began (``first_mode``: the mode of its first step,
    ``look_around`` unless a candidate was there to head for) and ended, its candidates at the end,
    and what the memory gave it at its start (the keyframes it was scored against, the remembered
    views that added goal points, their best score). ``run_id``: the console run that asked for
    it (set by ``console.home_memory``; None elsewhere, e.g. in an evaluation)."""

    goal_index: int
    keyframes_at_start: int = 0
    steps: int = 0
    first_mode: str | None = None
    final_mode: str | None = None
    final_event: str | None = None
    candidates: tuple[CandidateInfo, ...] = ()
    recalled_views: int = 0
    recall_best_score: float | None = None
    recall_ms: float = 0.0
    run_id: str | None = None

    def as_dict(self) -> dict[str, Any]:
        return {
            "goal_index": self.goal_index,
            "run_id": self.run_id,
            "keyframes_at_start": self.keyframes_at_start,
            "steps": self.steps,
            "first_mode": self.first_mode,
            "final_mode": self.final_mode,
            "final_event": self.final_event,
            "recalled_views": self.recalled_views,
            "recall_best_score": None if self.recall_best_score is None else round(self.recall_best_score, 1),
            "recall_ms": round(self.recall_ms, 1),
            "candidates": [
                {
                    "id": c.id,
                    "state": c.state,
                    "xy_m": [round(v, 3) for v in c.xy_m],
                    "best_score": round(c.best_score, 1),
                }
                for c in self.candidates
            ],
        }


class HomeMemory:
    """What the agent remembers of one home, in one odometry frame (see the module docstring).

    ``begin_goal`` at each goal's start (the agent's ``reset``), ``offer`` each searching frame,
    ``recall`` a new goal, ``note`` each step's record; ``clear`` forgets the home."""

    def __init__(self, config: MemoryConfig = MemoryConfig()) -> None:
        if config.cell_m <= 0 or config.heading_bins < 1 or config.max_keyframes < 0 or config.max_age_goals < 0:
            raise ValueError(f"bad memory config {config}")
        self.config = config
        self.clear()

    def clear(self) -> None:
        """Forget the home: the map, the keyframes and the goals (the next goal starts fresh)."""
        self.grid: GridMap | None = None
        self.goal_index = -1  # the goal under way (-1: none yet)
        self.goals: list[GoalSummary] = []
        self.last_pose: Pose2D | None = None
        self.matcher: str | None = None  # the matcher whose descriptors are kept
        self._keyframes: dict[tuple[int, int, int], Keyframe] = {}  # place and heading -> keyframe, oldest first
        self._next_id = 0

    # --- the store --------------------------------------------------------------------

    def __len__(self) -> int:
        return len(self._keyframes)

    @property
    def keyframes(self) -> tuple[Keyframe, ...]:
        """The keyframes, oldest first."""
        return tuple(self._keyframes.values())

    @property
    def size_bytes(self) -> int:
        """The keyframes' arrays (the map is counted apart: ``map_bytes``)."""
        return sum(k.nbytes for k in self._keyframes.values())

    @property
    def map_bytes(self) -> int:
        if self.grid is None:
            return 0
        return sum(int(getattr(self.grid.layers, n).nbytes) for n in self.grid.layers.names())

    def key(self, pose: Pose2D) -> tuple[int, int, int]:
        """The place and heading bin of a pose."""
        c, n = self.config.cell_m, self.config.heading_bins
        return (
            math.floor(pose.x_m / c),
            math.floor(pose.y_m / c),
            round(pose.yaw_rad / (2 * math.pi / n)) % n,
        )

    def offer(
        self, obs: Observation, features: Features, points_xyz: np.ndarray, matcher: str, min_points: int = 2
    ) -> Keyframe | None:
        """Keep this frame as the keyframe of its place and heading (the newest wins), unless
        fewer than ``min_points`` of its keypoints have a 3D point (it could localise nothing).
        ``points_xyz``: (N, 3) per keypoint, NaN rows where none (``GoalLocaliser.keypoint_points``).
        Returns the keyframe kept, or None."""
        if self.goal_index < 0:
            raise RuntimeError("HomeMemory.begin_goal() first")
        if self.config.max_keyframes == 0 or len(features) == 0 or features.descriptors is None:
            return None
        if len(points_xyz) != len(features):
            raise ValueError(f"{len(points_xyz)} points for {len(features)} keypoints")
        if int(np.isfinite(points_xyz).all(axis=1).sum()) < min_points:
            return None
        if self.matcher is not None and matcher != self.matcher:
            raise ValueError(f"this memory keeps {self.matcher} descriptors, not {matcher}'s: clear it first")
        self.matcher = matcher
        kf = Keyframe(
            self._next_id,
            self.goal_index,
            int(obs.step),
            obs.pose,
            matcher,
            np.array(features.keypoints_xy, np.float32, copy=True),
            _pack(features.descriptors, descriptors=True),
            (int(features.image_size_wh[0]), int(features.image_size_wh[1])),
            np.asarray(points_xyz, np.float32),
            _pack(dict(features.extra)),
        )
        self._next_id += 1
        key = self.key(obs.pose)
        self._keyframes.pop(key, None)  # the newest of a place and heading wins (and goes last)
        self._keyframes[key] = kf
        while len(self._keyframes) > self.config.max_keyframes:
            del self._keyframes[next(iter(self._keyframes))]
        return kf

    def restore(self, keyframes: list[Keyframe], next_id: int) -> None:
        """Put back keyframes read from a file (``console.home_memory``), oldest first, each under
        its place and heading, and the next keyframe id. Serialisation only: no bounds are applied."""
        self._keyframes = {self.key(kf.pose): kf for kf in keyframes}
        self._next_id = int(next_id)

    # --- goals ------------------------------------------------------------------------

    def begin_goal(self, mapping: MappingConfig, matcher: str | None = None) -> GridMap:
        """A new goal begins: forget keyframes older than ``max_age_goals`` goals and the last
        goal's candidate and search layers; returns the remembered map (a new one for the first goal).
        ``mapping`` must be the config the map was made with, and ``matcher`` (the agent's, None:
        none) the one whose descriptors are kept: a clear error otherwise, before the first step."""
        if self.grid is not None and self.grid.config != mapping:
            raise ValueError("the remembered map was made with another mapping config: clear the memory first")
        if matcher is not None and self.matcher is not None and matcher != self.matcher and self._keyframes:
            raise ValueError(f"this memory keeps {self.matcher} descriptors, not {matcher}'s: clear it first")
        self.goal_index += 1
        old = [k for k, kf in self._keyframes.items() if self.goal_index - kf.goal_index > self.config.max_age_goals]
        for k in old:
            del self._keyframes[k]
        self.goals.append(GoalSummary(self.goal_index, keyframes_at_start=len(self._keyframes)))
        if self.grid is None:
            self.grid = GridMap(mapping)
        else:
            # the goal cells, the rejected candidates and the given-up frontiers belong to the goal
            # that made them; the geometry and the explored area stay (module docstring)
            L = self.grid.layers
            for layer in (L.goal, L.blacklist, L.potential_blacklist, L.frontier_blacklist):
                layer[:] = False
        return self.grid

    def check_start(self, pose: Pose2D) -> float | None:
        """The distance from where the last goal ended to where this one starts (None: the first
        goal); logged as a warning above ``frame_check_m`` (the frames may differ: module docstring)."""
        if self.last_pose is None:
            return None
        d = pose.distance_to(self.last_pose)
        if d > self.config.frame_check_m:
            log.warning(
                "goal %d starts %.2f m from where goal %d ended: is the pose still in the same frame? "
                "(the memory of this home assumes it is)",
                self.goal_index,
                d,
                self.goal_index - 1,
            )
        return d

    def note(self, record: AgentRecord) -> None:
        """A step of the goal under way: its pose, and the goal's summary as it stands."""
        self.last_pose = record.pose
        g = self.goals[-1]
        self.goals[-1] = replace(
            g,
            steps=g.steps + 1,
            first_mode=record.mode if g.steps == 0 else g.first_mode,
            final_mode=record.mode,
            final_event=record.event,
            candidates=record.candidates,
        )

    def note_recall(self, views: int, best_score: float | None, ms: float) -> None:
        self.goals[-1] = replace(self.goals[-1], recalled_views=views, recall_best_score=best_score, recall_ms=ms)

    def summary(self) -> dict[str, Any]:
        """For records and the console (plain JSON values)."""
        return {
            "goal_index": self.goal_index,
            "keyframes": len(self._keyframes),
            "keyframe_bytes": self.size_bytes,
            "map_bytes": self.map_bytes,
            "goals": [g.as_dict() for g in self.goals],
        }

    # --- recall -------------------------------------------------------------------------

    @torch.inference_mode()
    def recall(
        self,
        goal: Features,
        matcher: Matcher,
        *,
        score_kind: ScoreKind,
        min_cosine: float,
        gate_threshold: float | None,
        top_k: int,
        min_score: float,
        exit_threshold: float | None = None,
    ) -> Recall:
        """Score a goal against every keyframe: the gate's mutual-nearest count (``min_cosine``)
        for all, the ``matcher`` on the ``top_k`` with the highest counts (at least
        ``gate_threshold``, when there is one), stopped after its exit layer when the exit stage's
        score is below ``exit_threshold`` (None: every layer; a matcher without an exit layer runs
        them all): the two stages of the gate the live searching frames face (agent/reid/gate.py).
        The recollections: those scoring at least ``min_score``."""
        kfs = list(self._keyframes.values())
        t0 = time.perf_counter()
        if not kfs or len(goal) == 0:
            return Recall(len(kfs), 0, (), (), 0.0, 0.0)
        if self.matcher is not None and matcher.name != self.matcher:
            raise ValueError(f"this memory keeps {self.matcher} descriptors, not {matcher.name}'s")
        gate = MNNGate(min_cosine)
        gate.set_goal(goal.descriptors)
        counts = [gate.score(_unpack(kf.descriptors)) for kf in kfs]
        order = sorted(range(len(kfs)), key=lambda i: (-counts[i], -kfs[i].id))  # ties: the newest first
        passed = [i for i in order if gate_threshold is None or counts[i] >= gate_threshold]
        t1 = time.perf_counter()
        scored, kept = [], []
        exit_on = exit_threshold is not None and bool(getattr(matcher, "exit_layer", 0))
        for i in passed[: max(0, top_k)]:
            kf = kfs[i]
            obs = kf.features()
            if exit_on:
                m = matcher.match(goal, obs, exit_below=(score_kind, exit_threshold))  # type: ignore[call-arg]
            else:
                m = matcher.match(goal, obs)
            s = score(m, score_kind)  # 0 when it stopped at the exit layer (no matches)
            scored.append((kf.id, float(counts[i]), s))
            if s >= min_score and len(m):
                kept.append(
                    Recollection(kf, float(counts[i]), s, goal.keypoints_xy[m.idx_goal], kf.points_xyz[m.idx_obs])
                )
        t2 = time.perf_counter()
        return Recall(len(kfs), len(passed), tuple(scored), tuple(kept), (t1 - t0) * 1e3, (t2 - t1) * 1e3)

    def localise(
        self,
        reid: ReIdentifier,
        localiser: GoalLocaliser,
        goal_mask: Callable[[], np.ndarray],
        *,
        top_k: int,
        min_score: float,
    ) -> Recall:
        """The goal of ``reid`` (set) against the memory (``recall``, with the gate's thresholds and
        the score of ``reid``): each recollection's matches on the goal mask (``goal_mask()``, called
        only when some keyframe reached ``min_score``) become goal points in ``localiser``, with
        its score, as the view ``Keyframe.frame_id`` taken from the keyframe's pose. Noted in the
        goal's summary and logged."""
        t = time.perf_counter()
        if reid.goal is None or not self._keyframes:
            return Recall(len(self._keyframes), 0, (), (), 0.0, 0.0)
        recall = self.recall(
            reid.goal,
            reid.matcher,
            score_kind=reid.config.score,
            min_cosine=reid.config.gate_min_cosine,
            gate_threshold=reid.gate_threshold,
            exit_threshold=reid.exit_threshold,
            top_k=top_k,
            min_score=min_score,
        )
        views = 0
        for r in recall.recollections:
            kf = r.keyframe
            added = localiser.add_points(r.goal_points(goal_mask()), r.score, kf.frame_id, (kf.pose.x_m, kf.pose.y_m))
            views += bool(len(added))
        ms = (time.perf_counter() - t) * 1e3
        self.note_recall(views, recall.best_score, ms)
        log.info(
            "goal %d against the memory: %d keyframes, %d past the gate, %d scored (best %s), %d added goal points "
            "(%.0f ms)",
            self.goal_index,
            recall.keyframes,
            recall.gated,
            len(recall.scored),
            "-" if recall.best_score is None else f"{recall.best_score:.1f}",
            views,
            ms,
        )
        return recall


class InHomeFrame:
    """A backend (``agent.types.Backend``) whose observations' poses are re-expressed in the memory's
    frame: ``origin`` (the pose of the backend's own start in that frame) composed with each pose
    (module docstring, "The frame")."""

    def __init__(self, backend: Backend, origin: Pose2D) -> None:
        self.backend = backend
        self.origin = origin

    def _shift(self, obs: Observation) -> Observation:
        return replace(obs, pose=self.origin.compose(obs.pose))

    def reset(self) -> Observation:
        return self._shift(self.backend.reset())

    def observe(self) -> Observation:
        return self._shift(self.backend.observe())

    def apply(self, action: Action) -> None:
        self.backend.apply(action)

    def close(self) -> None:
        self.backend.close()
