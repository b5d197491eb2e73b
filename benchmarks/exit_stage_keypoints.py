"""The re-ID gate's exit stage on fewer keypoints: what it would save and what it would let through.

    .venv/bin/python benchmarks/exit_stage_keypoints.py --episodes data/episodes/train30s1 \\
        [--count 30] [--keypoints 128 256 384 512] [--threads 1] [--json out.json]

The exit stage (agent/reid/gate.py) runs LighterGlue's first two layers on all 1,024 keypoints of
the goal and of the frame, on every searching frame past the first stage (about 60% of them), and
scores the frame with layer 2's assignment head. This measures the alternative: the same head on
the goal's and the frame's top-K keypoints by detection score (XFeat returns them best first), the
frames above the exit threshold then matched in full as today.

Frames: for each episode of ``--episodes`` (train), five views from the goal's viewpoints turned
towards the goal (jittered) and seven from random navigable poses, rendered by the simulator and
scored against the episode's goal image. For each frame: the full matcher's score, the exit
stage's score on all keypoints and on each top-K, each timed back to back. It prints, per setting,
the median time of the exit stage and its ratio to the full exit stage's, and at the threshold that
keeps every frame scoring at least tau/2 (the agent's potential evidence; tau from the calibration
file), the share of the frames below tau/2 that would still go on to the full matcher.

This is not the calibration (``imgnav calibrate --gate`` on recorded episode frames); it is the
measurement that decides whether one is worth making (docs/experiments/exit-stage-keypoints.md).
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

VIEWPOINT_VIEWS = 5
RANDOM_VIEWS = 7


def exit_score(matcher, goal, obs) -> tuple[float, float]:
    """(layer-k head's sum of confidences, ms): the exit stage alone (``exit_stage`` stops there)."""
    t = time.perf_counter()
    scores = matcher.exit_stage(goal, obs)
    ms = 1e3 * (time.perf_counter() - t)
    return (0.0 if scores is None else float(scores["conf"])), ms


def frames_of(episode_set, episode, rng: np.random.Generator):
    """(kind, rgb) views of the episode's home: at goal viewpoints towards the goal, and at random."""
    from agent.types import Pose2D
    from sim.world import SimWorld

    with SimWorld.from_seed(episode.scene_seed) as world:
        goal_xy = np.asarray(world.instance(episode.goal_instance_id).pose_xy_yaw[:2])
        vp = episode.viewpoints_array()
        poses = []
        for i in rng.choice(len(vp), size=min(VIEWPOINT_VIEWS, len(vp)), replace=False):
            x, y = vp[i]
            yaw = math.atan2(goal_xy[1] - y, goal_xy[0] - x) + rng.normal(0.0, 0.2)
            poses.append(("viewpoint", Pose2D(float(x), float(y), float(yaw))))
        grid = world.navigable_grid(0.1)
        free = np.argwhere(grid.navigable)
        for i in rng.choice(len(free), size=RANDOM_VIEWS, replace=False):
            r, c = free[i]
            x = grid.origin_xy_m[0] + (c + 0.5) * grid.resolution_m
            y = grid.origin_xy_m[1] + (r + 0.5) * grid.resolution_m
            poses.append(("random", Pose2D(float(x), float(y), float(rng.uniform(-math.pi, math.pi)))))
        return [(kind, world.render(p).rgb) for kind, p in poses]


def summarise(rows: list[dict], keypoints: list[int], tau: float) -> None:
    full = np.array([r["full"] for r in rows])
    near = full >= tau / 2
    print(
        f"{len(rows)} frames, {int(near.sum())} scoring at least tau/2 ({tau / 2:.1f}), {int((full >= tau).sum())} at "
        f"least tau; full match {statistics.median(r['full_ms'] for r in rows):.1f} ms (median)"
    )
    base_ms = statistics.median(r["ms_all"] for r in rows)
    print(
        "| exit stage on | ms (median) | / all keypoints | threshold keeping every frame >= tau/2 | frames < tau/2 going on |"
    )
    print("| --- | ---: | ---: | ---: | ---: |")
    for name in ["all"] + [str(k) for k in keypoints]:
        e = np.array([r[f"exit_{name}"] for r in rows])
        ms = statistics.median(r[f"ms_{name}"] for r in rows)
        bar = float(e[near].min()) if near.any() else float("nan")
        through = float((e[~near] >= bar).mean()) if (~near).any() else float("nan")
        label = "all 1,024" if name == "all" else f"top {name}"
        print(f"| {label} | {ms:.1f} | {ms / base_ms:.2f} | {bar:.2f} | {through:.1%} |")


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--episodes", required=True, help="a train episode set (goal images and viewpoints)")
    p.add_argument("--count", type=int, default=30, help="episodes (one home each in a --per-scene 1 set)")
    p.add_argument("--keypoints", type=int, nargs="+", default=[128, 256, 384, 512])
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", help="write every frame's scores and times here")
    args = p.parse_args()
    import torch
    from PIL import Image

    from agent.reid.base import score
    from agent.reid.identifier import ReIDConfig, resolve_tau
    from agent.reid.xfeat import XFeatLighterGlue, top_keypoints
    from sim.episodes import load_episode_set

    torch.set_num_threads(args.threads)
    es = load_episode_set(args.episodes)
    if any(e.split != "train" for e in es.episodes[: args.count]):
        raise SystemExit("measure on train episodes only")
    tau = resolve_tau(ReIDConfig())
    matcher = XFeatLighterGlue(exit_layer=ReIDConfig().gate_exit_layer)
    rng = np.random.default_rng(args.seed)
    rows: list[dict] = []
    for ep in es.episodes[: args.count]:
        goal = matcher.extract(np.asarray(Image.open(es.goal_image_path(ep)).convert("RGB")), 1024)
        for kind, rgb in frames_of(es, ep, rng):
            obs = matcher.extract(rgb, 1024)
            row: dict = {"episode": ep.episode_id, "kind": kind}
            t = time.perf_counter()
            row["full"] = score(matcher.match(goal, obs), "conf")
            row["full_ms"] = 1e3 * (time.perf_counter() - t)
            row["exit_all"], row["ms_all"] = exit_score(matcher, goal, obs)
            for k in args.keypoints:
                row[f"exit_{k}"], row[f"ms_{k}"] = exit_score(matcher, top_keypoints(goal, k), top_keypoints(obs, k))
            rows.append(row)
        print(f"  {ep.episode_id}: {len(rows)} frames", file=sys.stderr, flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(rows))
    print(f"{args.episodes}, {args.count} episodes, torch threads {args.threads}, tau {tau:.1f}")
    summarise(rows, args.keypoints, tau)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
