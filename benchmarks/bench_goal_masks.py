"""How well the goal-image mask sources find the goal instance, against the simulator's ground truth.

    .venv/bin/python benchmarks/bench_goal_masks.py [--homes 4] [--per-instance 2]

Goal images of train-split instances (``sim.goals.sample_goal_images``, which also returns
the ground-truth instance mask). For each mask source (``crop``: the paper's central crop;
``grabcut``: the class-agnostic GrabCut segmentation) prints the mean IoU with the truth,
the mean precision (share of the mask on the instance: what decides whether matched
keypoints selected by the mask lie on the object) and recall, and GrabCut's time.
"""

from __future__ import annotations

import argparse
import logging
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--homes", type=int, default=4)
    p.add_argument("--per-instance", type=int, default=2)
    p.add_argument("--scene-set", type=int, default=600)
    args = p.parse_args()
    logging.basicConfig(level=logging.WARNING)
    import numpy as np

    from agent.segmentation import SegmentationConfig, crop_mask, grabcut_mask
    from sim.episodes import scene_seed_for
    from sim.goals import sample_goal_images
    from sim.world import SimWorld

    stats: dict[str, dict[str, list[float]]] = {
        s: {"iou": [], "precision": [], "recall": []} for s in ("crop", "grabcut")
    }
    per_cat: dict[str, list[float]] = {}
    t_gc: list[float] = []
    for k in range(args.homes):
        seed = scene_seed_for("train", args.scene_set, k)
        with SimWorld.from_seed(seed) as world:
            for obj in world.home.instances:
                for gi in sample_goal_images(world, obj.object_id, args.per_instance, seed=(seed, obj.object_id, 3)):
                    gt = gi.mask
                    t = time.perf_counter()
                    gc = grabcut_mask(gi.rgb, SegmentationConfig())
                    t_gc.append((time.perf_counter() - t) * 1e3)
                    for name, m in (("crop", crop_mask(*gt.shape)), ("grabcut", gc)):
                        inter = float((m & gt).sum())
                        stats[name]["iou"].append(inter / max(float((m | gt).sum()), 1.0))
                        stats[name]["precision"].append(inter / max(float(m.sum()), 1.0))
                        stats[name]["recall"].append(inter / max(float(gt.sum()), 1.0))
                    per_cat.setdefault(obj.category, []).append(stats["grabcut"]["iou"][-1])
    n = len(t_gc)
    print(f"goal-image masks vs ground truth: {n} goal images of train instances ({args.homes} homes)")
    print("| source | IoU | precision | recall |")
    print("| --- | --- | --- | --- |")
    for name, s in stats.items():
        print(f"| {name} | {np.mean(s['iou']):.3f} | {np.mean(s['precision']):.3f} | {np.mean(s['recall']):.3f} |")
    print("| oracle | 1.000 | 1.000 | 1.000 |")
    print(
        "GrabCut IoU per category: " + ", ".join(f"{c} {np.mean(v):.2f} ({len(v)})" for c, v in sorted(per_cat.items()))
    )
    print(f"GrabCut time per goal image: median {statistics.median(t_gc):.0f} ms (runs once per episode)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
