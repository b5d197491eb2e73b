"""Goal candidates as objects with evidence (the policy's candidate memory).

A candidate is a cluster of goal points (``agent.localisation``) together with every view
that added points to it: the step, its re-ID score, the distance from the robot to what it
saw and the number of points (``localisation.View``). Its state follows from that evidence:

* ``confirmed``: some view scored at or above tau (the paper's detection), or a look from the
  verify ring confirmed it (``PolicyConfig.verify_ring_tau_ratio``);
* ``potential``: points, but no confirming view: only views below tau (the policy localises
  frames above a lower threshold, ``potential_tau_ratio``);
* ``rejected``: given up by the policy (verification failed, unreachable, no progress); its
  cells are blacklisted on the map (``GridMap.blacklist_cells``) and it is kept here only
  for the record.

The console and the failure analysis see all of them (``agent.types.CandidateInfo``).
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from agent.localisation import Candidate, GoalLocaliser, View
from agent.types import CandidateInfo


class CandidateState(str, enum.Enum):
    POTENTIAL = "potential"
    CONFIRMED = "confirmed"
    REJECTED = "rejected"


@dataclass(frozen=True, slots=True, eq=False)
class GoalCandidate:
    """A cluster with its evidence and state. ``cluster`` holds the points and cells."""

    cluster: Candidate
    state: CandidateState
    views: tuple[View, ...]

    @property
    def id(self) -> int:
        return self.cluster.id

    @property
    def remembered_only(self) -> bool:
        """All its views are remembered ones (the memory of the home gives them negative ids,
        ``agent.memory.Keyframe.frame_id``): none of this run's own frames added to it."""
        return bool(self.cluster.frames) and all(f < 0 for f in self.cluster.frames)

    @property
    def best_score(self) -> float:
        return max((v.score for v in self.views), default=0.0)

    def best_score_within(self, distance_m: float) -> float:
        return max((v.score for v in self.views if v.distance_m <= distance_m), default=0.0)


def evaluate(
    cluster: Candidate, localiser: GoalLocaliser, tau: float, confirmed_steps: frozenset[int] = frozenset()
) -> GoalCandidate:
    """The candidate's state from its views: a detection (score >= tau) confirms it, and so do
    the views in ``confirmed_steps`` whatever their score (looks from the verify ring)."""
    views = tuple(v for v in (localiser.view(f) for f in cluster.frames) if v is not None)
    confirming = [v for v in views if v.step in confirmed_steps or v.score >= tau]
    state = CandidateState.CONFIRMED if confirming else CandidateState.POTENTIAL
    return GoalCandidate(cluster, state, views)


class CandidateMemory:
    """Keeps the rejected candidates (for the record, and their clusters for the last resort)
    and turns clusters into ``CandidateInfo``."""

    def __init__(self) -> None:
        self.rejections = 0  # rejections so far (a candidate rejected twice counts twice)
        self._rejected: dict[int, CandidateInfo] = {}
        # id -> (cluster, its cells' centres in metres): map cells move when the map grows
        self._clusters: dict[int, tuple[Candidate, np.ndarray]] = {}

    def reject(
        self,
        cand: GoalCandidate | Candidate,
        robot_xy_m: tuple[float, float],
        cells_xy_m: np.ndarray | None = None,
        why: str | None = None,
    ) -> None:
        """Record a rejection (``why``: the policy's reason). ``cells_xy_m``: the centres of its
        cells (kept with the cluster for ``rejected_cluster``). Rejecting it again keeps the best
        evidence seen and the latest reason."""
        self.rejections += 1
        cl = cand.cluster if isinstance(cand, GoalCandidate) else cand
        n_views = len(cand.views) if isinstance(cand, GoalCandidate) else cl.n_frames
        best = cand.best_score if isinstance(cand, GoalCandidate) else cl.max_score
        old = self._rejected.get(cl.id)
        if old is not None:
            n_views, best = max(n_views, old.n_views), max(float(best), old.best_score)
        self._rejected[cl.id] = CandidateInfo(
            cl.id,
            CandidateState.REJECTED.value,
            cl.centroid_xy_m,
            n_views,
            float(best),
            math.dist(cl.centroid_xy_m, robot_xy_m),
            why,
        )
        if cells_xy_m is not None and len(cells_xy_m):
            self._clusters[cl.id] = (cl, np.asarray(cells_xy_m, np.float64).reshape(-1, 2))

    def was_rejected(self, cand_id: int) -> bool:
        return cand_id in self._rejected

    def best_rejected(self, exclude: frozenset[int] = frozenset()) -> int | None:
        """The id of the rejected candidate with the best evidence (highest score, then most
        views), among those with a kept cluster and not in ``exclude``; None when none is left."""
        pool = [r for k, r in self._rejected.items() if k in self._clusters and k not in exclude]
        if not pool:
            return None
        return max(pool, key=lambda r: (r.best_score, r.n_views, -r.id)).id

    def last_resort_next(self, current: int | None, tried: frozenset[int]) -> int | None:
        """The rejected candidate the last resort goes to next: the one under way (``current``),
        else the best not yet ``tried``; None when none is left."""
        return current if current is not None else self.best_rejected(exclude=tried)

    def best_score_of(self, cand_id: int) -> float:
        return self._rejected[cand_id].best_score

    def rejected_cluster(self, cand_id: int, cells_of: Callable[[np.ndarray], np.ndarray]) -> Candidate:
        """The rejected cluster with its cells re-indexed on the map as it is now
        (``cells_of``: metres -> cell indices, ``GridMap.xy_to_ij``)."""
        cl, xy = self._clusters[cand_id]
        return replace(cl, cells_ij=np.asarray(cells_of(xy), np.int64).reshape(-1, 2))

    def infos(self, live: list[GoalCandidate], robot_xy_m: tuple[float, float]) -> tuple[CandidateInfo, ...]:
        out = [
            CandidateInfo(
                c.id,
                c.state.value,
                c.cluster.centroid_xy_m,
                len(c.views),
                float(c.best_score),
                round(math.dist(c.cluster.centroid_xy_m, robot_xy_m), 3),
            )
            for c in live
        ]
        out += [
            CandidateInfo(
                r.id, r.state, r.xy_m, r.n_views, r.best_score, round(math.dist(r.xy_m, robot_xy_m), 3), r.why
            )
            for k, r in self._rejected.items()
            if all(c.id != k for c in live)
        ]
        return tuple(out)
