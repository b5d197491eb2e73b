"""The agent's map at one step of an episode, against the home's true free space (issue 30).

Runs the Mod-IIN agent on one episode (with ``imgnav eval``'s own flags, e.g. ``--realism
stretch``; the same episode and seed give the same run) up to step N, then prints what closes
its exploration: obstacle cells on truly free floor (where the robot's centre fits), those
confirmed by at most one frame, the frontier cells and how many the planner reaches; and draws
the map (PNG, north up) with the start-frame truth under it:

    grey / light grey  truly free, unexplored / explored     red     obstacle on an occupied cell
    orange             obstacle on truly free floor           magenta collision mark
    green              frontier cell                          cyan    given-up frontier
    white              the true path                          yellow  the goal's viewpoints

    python benchmarks/map_at_step.py --episodes data/episodes/train30s1 --agent modiin --out runs/x \\
        --realism stretch train-s1-0011-0 245 runs/map_0011.png

The agent's frame is the episode's start (the pose estimate starts there), so the truth is drawn
in it from the true start; under pose noise the believed map is off by the estimate's drift.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from agent.frontier import frontier_mask  # noqa: E402
from agent.loop import run_loop  # noqa: E402
from agent.policy import ModIINAgent  # noqa: E402
from agent.types import Pose2D  # noqa: E402
from sim.backend import SimBackend  # noqa: E402
from sim.episodes import Episode, load_episode_set  # noqa: E402
from sim.evaluation.cli import add_arguments, realism_of  # noqa: E402
from sim.evaluation.registry import get_spec  # noqa: E402
from sim.world import SimWorld  # noqa: E402


def episode_run(args: argparse.Namespace) -> tuple[Episode, SimWorld, SimBackend, ModIINAgent]:
    """The episode ``args.episode_id`` of ``args.episodes``: its world, its backend (with
    ``--realism``) and the Mod-IIN agent ``imgnav eval`` would run on it with these flags."""
    es = load_episode_set(args.episodes)
    (ep,) = [e for e in es.episodes if e.episode_id == args.episode_id]
    world = SimWorld.from_seed(ep.scene_seed)
    backend = SimBackend.for_episode(world, ep, es.goal_image_path(ep), realism=realism_of(args))
    agent = get_spec("modiin").make_agent(args, backend.oracle)
    assert isinstance(agent, ModIINAgent)
    return ep, world, backend, agent


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(parser)
    parser.add_argument("episode_id")
    parser.add_argument("step", type=int)
    parser.add_argument("png")
    args = parser.parse_args()
    ep, world, backend, agent = episode_run(args)
    run_loop(backend, agent, args.step, (), should_stop=lambda: backend.done)
    grid = agent.grid
    L = grid.layers
    h, w = grid.shape
    start = ep.start_pose_world

    def cell(p: Pose2D) -> tuple[int, int]:
        rel = p.relative_to(start)
        i, j = grid.xy_to_ij(np.array([[rel.x_m, rel.y_m]]))[0]
        return int(i), int(j)

    # the true free space, in the agent's (start) frame
    nav = world.navigable_grid(grid.resolution_m)
    ij = np.stack(np.meshgrid(np.arange(h), np.arange(w), indexing="ij"), -1).reshape(-1, 2)
    xy = grid.ij_to_xy(ij)
    c, s = math.cos(start.yaw_rad), math.sin(start.yaw_rad)
    wxy = np.stack([start.x_m + c * xy[:, 0] - s * xy[:, 1], start.y_m + s * xy[:, 0] + c * xy[:, 1]], 1)
    tij = nav.xy_to_ij(wxy)
    inside = nav.inside(tij)
    free = np.zeros(len(xy), bool)
    free[inside] = nav.navigable[tij[inside, 0], tij[inside, 1]]
    free = free.reshape(h, w)

    front = frontier_mask(grid)
    believed = backend.estimate_trajectory_world[-1].relative_to(start)
    field = agent.planner.distance_field(grid, believed)
    reach = np.isfinite(field.at(np.argwhere(front))) if front.any() else np.zeros(0, bool)
    phantom = L.obstacle & free
    print(
        f"{ep.episode_id} at step {backend.steps} ({agent.last_decision.event.value if agent.last_decision else '-'})"
    )
    print(
        f"  obstacle cells on truly free floor: {int(phantom.sum())}, of which one frame's evidence: "
        f"{int((phantom & (L.obstacle_evidence <= 1)).sum())}"
    )
    print(f"  frontier cells: {int(front.sum())}, reachable by the planner: {int(reach.sum())}")
    print(f"  truly free cells: {int(free.sum())}, explored: {int((free & L.explored).sum())}")

    img = np.full((h, w, 3), 40, np.uint8)
    img[free] = (90, 90, 90)
    img[free & L.explored] = (160, 160, 160)
    img[L.obstacle] = (0, 0, 200)
    img[phantom] = (0, 140, 255)
    img[L.collision] = (255, 0, 255)
    img[L.frontier_blacklist & ~L.obstacle] = (255, 255, 0)
    img[front] = (0, 220, 0)
    for p in backend.trajectory_world:
        i, j = cell(p)
        if 0 <= i < h and 0 <= j < w:
            img[i, j] = (255, 255, 255)
    for vx, vy in ep.viewpoints_xy_m:
        i, j = cell(Pose2D(vx, vy, 0.0))
        cv2.circle(img, (j, i), 2, (0, 255, 255), -1)
    img = cv2.resize(img[::-1], (3 * w, 3 * h), interpolation=cv2.INTER_NEAREST)
    cv2.imwrite(args.png, img)
    print(f"  map: {args.png}")
    backend.close()
    world.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
