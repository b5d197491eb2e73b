"""Frame-to-map alignment as an estimator (issue 30): how often each setting corrects, and whether
its corrections move the pose towards the truth.

Runs the Mod-IIN agent with alignment off (``imgnav eval``'s flags, e.g. ``--realism stretch``;
``--modiin-reid oracle --modiin-loc oracle`` makes it cheap) on some episodes. Before each step,
every setting (``--setting NAME:key=value,...``, fields of ``agent.alignment.AlignmentConfig``)
aligns the frame against the map as it stands, and the proposal is compared with the true pose in
the agent's frame. With exact pose (``clean``) any correction is an error. Prints per setting:
steps corrected, the heading and position error before and after over the corrected steps, and
the share of corrections that made the heading worse by more than a step of the search.

    python benchmarks/alignment_check.py --episodes data/episodes/train30s1 --agent modiin \\
        --out runs/x --realism stretch --modiin-reid oracle --modiin-loc oracle --steps 200 \\
        --setting base: --setting yaw_only:max_shift_m=0 train-s1-0011-0 train-s1-0005-0
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from agent.alignment import Alignment, AlignmentConfig, agrees  # noqa: E402
from agent.loop import run_loop  # noqa: E402
from agent.types import Observation, Pose2D, wrap_angle  # noqa: E402
from sim.backend import SimBackend  # noqa: E402
from sim.episodes import load_episode_set  # noqa: E402
from sim.evaluation.cli import add_arguments, realism_of  # noqa: E402
from sim.evaluation.registry import get_spec  # noqa: E402
from sim.world import SimWorld  # noqa: E402


def parse_setting(text: str) -> tuple[str, AlignmentConfig]:
    name, _, rest = text.partition(":")
    changes = {}
    for item in filter(None, rest.split(",")):
        key, _, value = item.partition("=")
        changes[key.strip()] = yaml.safe_load(value)
    return name, dataclasses.replace(AlignmentConfig(), **changes)


def errors(pose: Pose2D, true: Pose2D) -> tuple[float, float]:
    return abs(math.degrees(wrap_angle(pose.yaw_rad - true.yaw_rad))), pose.distance_to(true)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(parser)
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--setting", action="append", default=[], help="NAME:key=value,... (repeatable)")
    parser.add_argument("--verbose", action="store_true", help="print every correction")
    parser.add_argument("episode_ids", nargs="+")
    args = parser.parse_args()
    args.modiin_set = [*args.modiin_set, "alignment.enabled=false"]
    settings = [parse_setting(s) for s in (args.setting or ["default:"])]
    es = load_episode_set(args.episodes)
    rows: dict[str, list[tuple[float, float, float, float, bool]]] = {n: [] for n, _ in settings}
    steps = 0
    for episode_id in args.episode_ids:
        (ep,) = [e for e in es.episodes if e.episode_id == episode_id]
        world = SimWorld.from_seed(ep.scene_seed)
        backend = SimBackend.for_episode(world, ep, es.goal_image_path(ep), realism=realism_of(args))
        agent = get_spec("modiin").make_agent(args, backend.oracle)
        start = ep.start_pose_world  # the run frame: the estimate starts at the true start
        act = agent.act
        previous: dict[str, Alignment] = {}

        def probe(
            obs: Observation,
            act=act,
            agent=agent,
            backend=backend,
            start=start,
            episode_id=episode_id,
            previous=previous,
        ) -> object:
            if agent.last_record is not None:  # from the second frame: the map has something
                true = backend.oracle.pose_world.relative_to(start)
                frame = agent.grid.lift(obs)
                y0, p0 = errors(obs.pose, true)
                for name, cfg in settings:
                    proposal = agent.grid.align(frame, cfg)
                    taken = agrees(previous.get(name), proposal, cfg)  # as the agent takes it
                    previous[name] = proposal
                    got = proposal if taken else Alignment(obs.pose, False)
                    y1, p1 = errors(got.pose, true)
                    rows[name].append((y0, y1, p0, p1, got.corrected))
                    if args.verbose and proposal.corrected:
                        got = proposal
                        y1, p1 = errors(got.pose, true)
                        print(f"  {'taken' if taken else 'alone'}", end="")
                        print(
                            f"  {episode_id} step {obs.step} {name}: yaw {y0:.2f} -> {y1:.2f} deg, "
                            f"score {got.estimate_score_m:.4f} -> {got.score_m:.4f} m, "
                            f"inliers {got.estimate_inlier_share:.2f} -> {got.inlier_share:.2f}"
                        )
            return act(obs)

        agent.act = probe  # type: ignore[method-assign]
        result = run_loop(backend, agent, args.steps, (), should_stop=lambda backend=backend: backend.done)
        steps += result.n_steps
        backend.close()
        world.close()
    print(f"{len(args.episode_ids)} episodes, {steps} steps, realism {args.realism}")
    print(f"{'setting':<14} corrected  yaw err before->after (median, corrected)  worse  pos err before->after")
    for name, _ in settings:
        r = np.array(rows[name], float).reshape(-1, 5)
        c = r[:, 4] > 0
        yb, ya, pb, pa = (np.median(r[c, k]) if c.any() else math.nan for k in range(4))
        worse = float(np.mean(r[c, 1] > r[c, 0] + 0.25)) if c.any() else math.nan
        print(
            f"{name:<14} {int(c.sum()):>4}/{len(r):<4} {yb:6.2f} -> {ya:5.2f} deg"
            f"{'':<24} {worse:5.2f}  {pb:.3f} -> {pa:.3f} m"
        )
        print(
            f"{'':<14} all steps: yaw err median {np.median(r[:, 0]):.2f} -> {np.median(r[:, 1]):.2f} deg, "
            f"p90 {np.percentile(r[:, 0], 90):.2f} -> {np.percentile(r[:, 1], 90):.2f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
