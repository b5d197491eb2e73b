"""The task's metrics, exactly as docs/architecture.md section 1 defines them.

* success: the agent issued STOP within 0.1 m (inclusive) of a goal viewpoint.
* SPL: success * shortest / max(path taken, shortest), where shortest is the
  geodesic distance from the start to the nearest viewpoint and the path taken
  is the length the robot actually moved (blocked moves add nothing).
* NE: geodesic distance from the stop position to the nearest viewpoint.
* Max-ST: share of episodes that used the whole step budget without stopping.

Success varies far more between homes than between episodes of one home, so episodes are
not independent samples: SR and SPL get a 95% interval from a percentile bootstrap over
homes (resample the homes with replacement, keep all episodes of each; ``bootstrap_ci``),
whenever the records say which home (``scene_seed``) they come from.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from agent.types import VIEWPOINT_SUCCESS_RADIUS_M

# "within 0.1 m" is inclusive; this absorbs floating-point noise in the subtraction
# (1.1 - 1.0 is 0.10000000000000009), far below anything physical.
BOUNDARY_TOLERANCE_M = 1e-9


@dataclass(frozen=True, slots=True)
class EpisodeMetrics:
    success: bool
    spl: float
    ne_m: float  # geodesic distance from the stop position to the nearest viewpoint
    steps: int
    path_length_m: float
    shortest_path_m: float
    max_steps_reached: bool
    called_stop: bool
    stop_to_viewpoint_m: float  # Euclidean distance to the nearest viewpoint

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def nearest_viewpoint_distance_m(xy_m: tuple[float, float], viewpoints_xy_m: np.ndarray) -> float:
    vp = np.asarray(viewpoints_xy_m, dtype=np.float64).reshape(-1, 2)
    if len(vp) == 0:
        return math.inf
    return float(np.min(np.hypot(vp[:, 0] - xy_m[0], vp[:, 1] - xy_m[1])))


def is_success(
    called_stop: bool,
    stop_xy_m: tuple[float, float],
    viewpoints_xy_m: np.ndarray,
    radius_m: float = VIEWPOINT_SUCCESS_RADIUS_M,
) -> bool:
    return (
        bool(called_stop)
        and nearest_viewpoint_distance_m(stop_xy_m, viewpoints_xy_m) <= radius_m + BOUNDARY_TOLERANCE_M
    )


def spl(success: bool, shortest_path_m: float, path_length_m: float) -> float:
    """Success weighted by path length (Anderson et al. 2018)."""
    if not success:
        return 0.0
    denom = max(path_length_m, shortest_path_m)
    return 1.0 if denom <= 0.0 else shortest_path_m / denom


def episode_metrics(
    *,
    called_stop: bool,
    stop_xy_m: tuple[float, float],
    viewpoints_xy_m: np.ndarray,
    steps: int,
    max_steps: int,
    path_length_m: float,
    shortest_path_m: float,
    stop_geodesic_m: float,
) -> EpisodeMetrics:
    ok = is_success(called_stop, stop_xy_m, viewpoints_xy_m)
    return EpisodeMetrics(
        success=ok,
        spl=spl(ok, shortest_path_m, path_length_m),
        ne_m=float(stop_geodesic_m),
        steps=int(steps),
        path_length_m=float(path_length_m),
        shortest_path_m=float(shortest_path_m),
        max_steps_reached=(not called_stop) and steps >= max_steps,
        called_stop=bool(called_stop),
        stop_to_viewpoint_m=nearest_viewpoint_distance_m(stop_xy_m, viewpoints_xy_m),
    )


BOOTSTRAP_RESAMPLES = 2000


def bootstrap_ci(
    values: Iterable[float],
    groups: Iterable[Any],
    level: float = 0.95,
    resamples: int = BOOTSTRAP_RESAMPLES,
    seed: int = 0,
) -> tuple[float, float]:
    """Percentile-bootstrap interval of the mean of ``values`` (one per episode) over resampled
    ``groups`` (homes): each resample draws as many homes as there are, with replacement, and
    averages all episodes of the drawn homes. Deterministic for a given ``seed``."""
    v = np.asarray(list(values), np.float64)
    g = list(groups)
    if len(v) != len(g):
        raise ValueError("values and groups differ in length")
    if len(v) == 0:
        return (math.nan, math.nan)
    keys = {k: i for i, k in enumerate(dict.fromkeys(g))}
    idx = np.fromiter((keys[k] for k in g), np.int64, len(g))
    sums = np.bincount(idx, weights=v, minlength=len(keys))
    counts = np.bincount(idx, minlength=len(keys)).astype(np.float64)
    rng = np.random.default_rng(seed)
    draw = rng.integers(0, len(keys), size=(resamples, len(keys)))
    stats = sums[draw].sum(axis=1) / counts[draw].sum(axis=1)
    alpha = (1.0 - level) / 2.0
    lo, hi = np.quantile(stats, [alpha, 1.0 - alpha])
    return (round(float(lo), 4), round(float(hi), 4))


def _intervals(rows: list[Mapping[str, Any]]) -> dict[str, Any]:
    """SR and SPL 95% intervals from a bootstrap over homes (empty without ``scene_seed``)."""
    if not rows or any("scene_seed" not in r for r in rows):
        return {}
    homes = [r["scene_seed"] for r in rows]
    return {
        "homes": len(set(homes)),
        "sr_ci95": list(bootstrap_ci([float(bool(r["success"])) for r in rows], homes)),
        "spl_ci95": list(bootstrap_ci([float(r["spl"]) for r in rows], homes)),
    }


def _block(rows: list[Mapping[str, Any]]) -> dict[str, Any]:
    n = len(rows)
    if n == 0:
        return {"episodes": 0, "sr": 0.0, "spl": 0.0, "ne": 0.0, "max_st": 0.0}
    ne = [float(r["ne"]) for r in rows]
    finite = [v for v in ne if math.isfinite(v)]
    return {
        "episodes": n,
        "sr": sum(bool(r["success"]) for r in rows) / n,
        "spl": sum(float(r["spl"]) for r in rows) / n,
        # an unreachable stop position has infinite NE; it is averaged over the finite ones and counted
        "ne": (sum(finite) / len(finite)) if finite else math.inf,
        "ne_unreachable": n - len(finite),
        "max_st": sum(bool(r["max_steps_reached"]) for r in rows) / n,
        **_intervals(rows),
    }


def aggregate(records: Iterable[Mapping[str, Any]]) -> dict[str, Any]:
    """Overall and per-category figures from per-episode records.

    Each record needs ``success``, ``spl``, ``ne`` (metres), ``max_steps_reached`` and
    ``category``; with ``scene_seed`` in every record, each block also has ``homes``,
    ``sr_ci95`` and ``spl_ci95`` ([low, high], bootstrap over homes). Returns
    ``{"sr", "spl", "ne", "max_st", "episodes", ..., "per_category": {...}}``."""
    rows = list(records)
    out = _block(rows)
    by_cat: dict[str, list[Mapping[str, Any]]] = defaultdict(list)
    for r in rows:
        by_cat[str(r["category"])].append(r)
    out["per_category"] = {cat: _block(v) for cat, v in sorted(by_cat.items())}
    return out
