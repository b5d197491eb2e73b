"""Pair scoring of ``imgnav calibrate --ray ADDRESS`` as Ray tasks (docs/architecture.md section 9).

Matching the goal-image pairs is the cost of calibration (12,500 pairs at ~0.1 s each on
this machine's 2 cores, against 1,000 extractions at ~0.04 s). The pairs, sorted, are cut
into chunks; one Ray task (``num_cpus=1``, one torch thread) scores a chunk and returns its
two small score arrays, (conf, count) per pair, exactly what ``calibration_core.score_pairs``
gives locally.

* No shared filesystem: each image's PNG bytes go to the object store once
  (``ray.put``); a task fetches the images its chunk needs and extracts their features
  itself, keeping them in a per-process cache, so a worker extracts an image at most once
  whatever number of chunks it runs.
* Backpressure: at most ``max_in_flight`` chunks submitted (default twice the CPUs).
* Faults: a chunk is a pure function of its inputs, so Ray's own task retries apply
  (``max_retries`` for lost workers and nodes; Python exceptions are not retried). A chunk
  that still fails stops the calibration with its error: a threshold from a subset of
  the pairs would not be the protocol's. Ctrl-C cancels the chunks in flight; a re-run
  reuses the cached goal images and scores every pair again.
"""

from __future__ import annotations

import logging
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from sim.evaluation.ray_backend import RayOptions, connect, import_ray

log = logging.getLogger(__name__)

_FEATURES: dict[tuple, Any] = {}  # per worker process: (matcher key, image key) -> Features
_MATCHERS: dict[tuple, Any] = {}
_CACHE_IMAGES = 2000  # bound on cached features per worker process (~0.3 MB each)


@dataclass(frozen=True, slots=True)
class ChunkResult:
    """conf, count: (P,) float64 per pair of the chunk; seconds spent extracting and matching."""

    conf: np.ndarray
    count: np.ndarray
    extract_s: float
    match_s: float
    extracted: int


def _matcher_key(cfg: Any) -> tuple:
    from agent.reid.identifier import matcher_key

    return matcher_key(cfg) + (cfg.goal_max_keypoints,)  # features are cached per key too


def score_chunk(reid_cfg: Any, image_keys: list[str], image_refs: list[Any], pairs: np.ndarray) -> ChunkResult:
    """Ray task: score ``pairs`` ((P, 2) indices into ``image_keys``/``image_refs``)."""
    import sys
    from dataclasses import replace

    import cv2
    import ray

    from agent.reid.identifier import make_matcher

    reid_cfg = replace(reid_cfg, num_threads=1)
    key = _matcher_key(reid_cfg)
    if key not in _MATCHERS:
        _MATCHERS[key] = make_matcher(reid_cfg)
    if "torch" in sys.modules:  # one CPU per task: one torch thread (OMP_NUM_THREADS alone is not enough)
        sys.modules["torch"].set_num_threads(1)
    matcher = _MATCHERS[key]
    used = sorted(set(pairs.reshape(-1).tolist()))
    missing = [i for i in used if (key, image_keys[i]) not in _FEATURES]
    t0 = time.perf_counter()
    for i, png in zip(missing, ray.get([image_refs[i] for i in missing])):
        bgr = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
        if bgr is None:
            raise ValueError(f"goal image {image_keys[i]}: bytes are not an image")
        if len(_FEATURES) >= _CACHE_IMAGES:
            _FEATURES.pop(next(iter(_FEATURES)))
        _FEATURES[(key, image_keys[i])] = matcher.extract(
            cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), reid_cfg.goal_max_keypoints
        )
    extract_s = time.perf_counter() - t0
    feats = {i: _FEATURES[(key, image_keys[i])] for i in used}
    t0 = time.perf_counter()
    conf = np.zeros(len(pairs), np.float64)
    count = np.zeros(len(pairs), np.float64)
    for k, (a, b) in enumerate(pairs):
        m = matcher.match(feats[int(a)], feats[int(b)])
        conf[k] = float(np.sum(m.confidence, dtype=np.float64))
        count[k] = float(len(m))
    return ChunkResult(conf, count, extract_s, time.perf_counter() - t0, len(missing))


def score_pairs_on_ray(
    options: RayOptions,
    reid_cfg: Any,
    image_keys: Sequence[str],
    image_png: Sequence[bytes],
    pairs: np.ndarray,
    chunk_pairs: int = 200,
    progress: Any = None,
) -> tuple[np.ndarray, np.ndarray, dict]:
    """(conf, count) per pair as ``calibration_core.score_pairs`` computes them, plus timing
    (summed over the tasks): ``{"extract_s", "match_s", "extracted", "tasks", "wall_s"}``."""
    ray = import_ray()
    try:
        disconnect = connect(options)
    except ValueError as exc:  # calibrate reports RuntimeErrors as a clean exit 2
        raise RuntimeError(str(exc)) from exc
    t_wall = time.perf_counter()
    task = ray.remote(num_cpus=1, max_retries=options.max_retries, retry_exceptions=False)(score_chunk)
    conf = np.zeros(len(pairs), np.float64)
    count = np.zeros(len(pairs), np.float64)
    # sorted pairs: a chunk holds few first images, so fewer images per task
    order = np.lexsort((pairs[:, 1], pairs[:, 0]))
    chunks = deque(order[k : k + chunk_pairs] for k in range(0, len(order), chunk_pairs))
    stats = {"extract_s": 0.0, "match_s": 0.0, "extracted": 0, "tasks": len(chunks)}
    in_flight: dict[Any, np.ndarray] = {}
    try:
        refs = [ray.put(b) for b in image_png]
        keys = list(image_keys)
        while chunks or in_flight:
            limit = options.max_in_flight or 2 * max(1, int(ray.cluster_resources().get("CPU", 1)))
            while chunks and len(in_flight) < limit:
                idx = chunks.popleft()
                in_flight[task.remote(reid_cfg, keys, refs, pairs[idx])] = idx
            ready, _ = ray.wait(list(in_flight), num_returns=1)
            for ref in ready:
                idx = in_flight.pop(ref)
                try:
                    res: ChunkResult = ray.get(ref)
                except ray.exceptions.RayError as exc:
                    raise RuntimeError(
                        f"a calibration chunk of {len(idx)} pairs failed after {options.max_retries} retries: {exc}"
                    ) from exc
                conf[idx], count[idx] = res.conf, res.count
                stats["extract_s"] += res.extract_s
                stats["match_s"] += res.match_s
                stats["extracted"] += res.extracted
                if progress is not None:
                    progress.update(len(idx))
    except BaseException:  # Ctrl-C or a failed chunk: stop the chunks in flight
        for ref in in_flight:
            ray.cancel(ref, force=True)
        raise
    finally:
        if disconnect:
            ray.shutdown()
    stats["wall_s"] = time.perf_counter() - t_wall
    return conf, count, stats
