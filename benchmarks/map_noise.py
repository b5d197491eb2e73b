"""How depth noise spoils the agent's map, and what the mapping settings do about it (issue 30).

Replays the true poses of recorded episodes (an ``imgnav eval`` output), renders each frame,
and builds the agent's top-down map from exact depth and from the realism profile's depth,
with several mapping settings. The pose is exact (the depth alone is measured) unless
``--believed``: then the noisy maps are placed at the poses the agent believed (the records of a
run under the profile hold them), as the agent's own map was. Prints per
setting: phantom obstacle cells (obstacles in open floor, well clear of every real obstacle, as
``sim.evaluation.modiin`` counts them), and the share of the exact-depth map's obstacle cells
the setting still finds (within one cell).

    python benchmarks/map_noise.py --eval runs/i29_after_train10 --episodes data/episodes/train10 --every 3
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from agent.mapping import GridMap, MappingConfig  # noqa: E402
from agent.types import Observation, Pose2D  # noqa: E402
from sim.camera import SIM_CAMERA  # noqa: E402
from sim.episodes import load_episode_set  # noqa: E402
from sim.evaluation.modiin import _open_floor  # noqa: E402
from sim.evaluation.runner import read_records  # noqa: E402
from sim.navigation import GRID_RESOLUTION_M  # noqa: E402
from sim.realism import PROFILES, noisy_depth  # noqa: E402
from sim.world import SimWorld  # noqa: E402

# every setting written out (the defaults may move): the unfiltered map is the reference
UNFILTERED = MappingConfig(obstacle_min_points=1, depth_consistency=0.0, obstacle_evidence_cap=0)
SETTINGS: dict[str, MappingConfig] = {
    "unfiltered (min 1 point)": UNFILTERED,
    "min 3 points": MappingConfig(obstacle_min_points=3, depth_consistency=0.0, obstacle_evidence_cap=0),
    "consistency 5%": MappingConfig(obstacle_min_points=1, depth_consistency=0.05, obstacle_evidence_cap=0),
    "consistency + min 3": MappingConfig(obstacle_min_points=3, depth_consistency=0.05, obstacle_evidence_cap=0),
    "+ evidence cap 1": MappingConfig(obstacle_min_points=3, depth_consistency=0.05, obstacle_evidence_cap=1),
    "+ evidence cap 3": MappingConfig(obstacle_min_points=3, depth_consistency=0.05, obstacle_evidence_cap=3),
    "+ evidence cap 3, to 5 m": MappingConfig(
        obstacle_min_points=3, depth_consistency=0.05, obstacle_evidence_cap=3, clear_max_range_m=5.0
    ),
    "+ evidence cap 10": MappingConfig(obstacle_min_points=3, depth_consistency=0.05, obstacle_evidence_cap=10),
    "+ evidence cap 3, depth to 3 m": MappingConfig(
        obstacle_min_points=3, depth_consistency=0.05, obstacle_evidence_cap=3, max_depth_m=3.0
    ),
    "+ evidence cap 3, depth to 2 m": MappingConfig(
        obstacle_min_points=3, depth_consistency=0.05, obstacle_evidence_cap=3, max_depth_m=2.0
    ),
}
# settings also given exact depth at the true pose: what they cost where nothing is wrong
EXACT_SETTINGS: dict[str, MappingConfig] = {
    "exact: consistency + min 3": SETTINGS["consistency + min 3"],
    "exact: + evidence cap 3": SETTINGS["+ evidence cap 3"],
}


def _cells_world(grid: GridMap, start: Pose2D) -> np.ndarray:
    ij = np.argwhere(grid.layers.obstacle)
    return start.transform_xy(grid.ij_to_xy(ij)) if len(ij) else np.zeros((0, 2))


def _ghosts(xy: np.ndarray, world: SimWorld) -> int:
    nav = world.navigable_grid(GRID_RESOLUTION_M)
    clear = _open_floor(nav)
    ij = nav.xy_to_ij(xy)
    ok = (ij[:, 0] >= 0) & (ij[:, 0] < clear.shape[0]) & (ij[:, 1] >= 0) & (ij[:, 1] < clear.shape[1])
    return int(np.count_nonzero(clear[ij[ok, 0], ij[ok, 1]]))


def _found(reference: np.ndarray, xy: np.ndarray, res: float) -> float:
    """Share of reference obstacle positions with a setting's obstacle within one cell."""
    if len(reference) == 0:
        return 1.0
    if len(xy) == 0:
        return 0.0
    lo = np.minimum(reference.min(axis=0), xy.min(axis=0)) - 1.0
    hi = np.maximum(reference.max(axis=0), xy.max(axis=0)) + 1.0
    shape = tuple(int(v) for v in np.ceil((hi - lo)[::-1] / res) + 1)
    img = np.zeros(shape, np.uint8)
    ij = np.floor((xy - lo)[:, ::-1] / res).astype(int)
    img[ij[:, 0], ij[:, 1]] = 1
    img = cv2.dilate(img, np.ones((3, 3), np.uint8))
    rij = np.floor((reference - lo)[:, ::-1] / res).astype(int)
    return float(img[rij[:, 0], rij[:, 1]].mean())


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--eval", required=True, help="an imgnav eval output (episodes.jsonl with trajectories)")
    ap.add_argument("--episodes", required=True, help="its episode set")
    ap.add_argument("--every", type=int, default=3, help="use every Nth pose of each trajectory")
    ap.add_argument("--max-frames", type=int, default=120)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--believed",
        action="store_true",
        help="place the noisy maps at the records' believed poses (poses_estimate_world)",
    )
    ap.add_argument("--episode", action="append", default=[], help="only this episode id (repeatable)")
    ap.add_argument(
        "--setting", action="append", default=[], help="only the settings whose name contains this (repeatable)"
    )
    args = ap.parse_args()
    settings = {k: v for k, v in SETTINGS.items() if not args.setting or any(s in k for s in args.setting)}
    exact_settings = {k: v for k, v in EXACT_SETTINGS.items() if not args.setting or any(s in k for s in args.setting)}
    es = load_episode_set(args.episodes)
    by_id = {e.episode_id: e for e in es.episodes}
    model = PROFILES["stretch"].depth
    assert model is not None
    totals = {name: [0, []] for name in [*settings, *exact_settings]}  # ghosts, found shares
    for rec in read_records(Path(args.eval)):
        ep = by_id.get(rec["episode_id"])
        if ep is None or (args.episode and ep.episode_id not in args.episode):
            continue
        rng = np.random.default_rng([args.seed, ep.scene_seed])
        world = SimWorld.from_seed(ep.scene_seed)
        start = ep.start_pose_world
        traj = rec["trajectory"]
        believed_key = "poses_estimate_world" if args.believed else "poses_world"
        if not traj.get(believed_key):
            print(f"{ep.episode_id}: no {believed_key} in the record (run it under the profile)", file=sys.stderr)
            return 2
        poses = [Pose2D(*p) for p in traj["poses_world"]][:: args.every][: args.max_frames]
        believed = [Pose2D(*p) for p in traj[believed_key]][:: args.every][: args.max_frames]
        exact = GridMap(UNFILTERED)
        noisy = {name: GridMap(cfg) for name, cfg in settings.items()}
        clean = {name: GridMap(cfg) for name, cfg in exact_settings.items()}
        for p, b in zip(poses, believed, strict=True):
            r = world.render(p, SIM_CAMERA)
            kw = dict(
                rgb=r.rgb, intrinsics=SIM_CAMERA.intrinsics, goal_image=r.rgb, camera_height_m=SIM_CAMERA.height_m
            )
            for g in (exact, *clean.values()):
                g.update(Observation(depth_m=r.depth_m, pose=p.relative_to(start), **kw))
            d = noisy_depth(r.depth_m, r.rgb, SIM_CAMERA.intrinsics.fx, model, rng)
            for g in noisy.values():
                g.update(Observation(depth_m=d, pose=b.relative_to(start), **kw))
        ref = _cells_world(exact, start)
        row = [f"{ep.episode_id}: exact ghosts {_ghosts(ref, world)}"]
        for name, g in (noisy | clean).items():
            xy = _cells_world(g, start)
            ghosts, found = _ghosts(xy, world), _found(ref, xy, exact.resolution_m)
            totals[name][0] += ghosts
            totals[name][1].append(found)
            row.append(f"{name}: {ghosts} / {found:.2f}")
        print(" | ".join(row), flush=True)
        world.close()
    print("\nsetting: phantom obstacle cells (sum) / exact map's obstacles found (median share)")
    for name, (ghosts, found) in totals.items():
        print(f"  {name:32s} {ghosts:6d}   {np.median(found):.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
