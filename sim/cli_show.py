"""``imgnav show``: pictures for people, as PNG.

    imgnav show --scene 100000000 --out show/            # top-down map of a home
    imgnav show --scene 100000000 --gallery --out show/  # + one goal image per instance
    imgnav show --episodes data/episodes/val --episode val-s0-0000-1 --eval runs/oracle-val --out show/
    imgnav show --episodes data/episodes/val --out show/ # goal-image sheet of the set (+ map of each scene)

Maps show rooms, labelled goal instances (coloured by category), clutter (grey),
walls, non-navigable floor (darker); for an episode its start (red), the goal's
viewpoints (green) and the path an agent took (blue, from an eval's episodes.jsonl); a run
under a realism profile's pose noise also shows the path the agent believed it took (orange) and the largest gap between the two.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
from pathlib import Path

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scene", type=int, default=None, help="scene seed of a home to draw")
    parser.add_argument("--episodes", default=None, help="episode-set directory")
    parser.add_argument("--episode", default=None, help="one episode id of the set (map with start, viewpoints, path)")
    parser.add_argument("--eval", default=None, help="an `imgnav eval` output directory: draw the agent's path")
    parser.add_argument("--gallery", action="store_true", help="with --scene: render one goal image per instance")
    parser.add_argument("--limit", type=int, default=40, help="at most this many goal images / scene maps")
    parser.add_argument("--out", default="show", help="output directory")


def _save(path: Path, rgb) -> None:
    from sim.episodes import write_rgb

    write_rgb(path, rgb)
    log.info("wrote %s", path)


def _episode_map(es, episode, eval_dir: str | None):
    from sim.scene_gen import generate_home
    from sim.show import TopDown

    td = TopDown(generate_home(episode.scene_seed)).draw_home()
    td.draw_points(episode.viewpoints_array(), (0, 190, 0), 2)
    p = episode.start_pose_world
    td.draw_pose(p.x_m, p.y_m, p.yaw_rad, (220, 0, 0), "start")
    title = f"{episode.episode_id}: {episode.goal_category} #{episode.goal_instance_id}, geodesic {episode.geodesic_distance_m:.2f} m"
    if eval_dir:
        rec = _find_record(Path(eval_dir), episode.episode_id)
        if rec is None:
            log.warning("no record of %s in %s", episode.episode_id, eval_dir)
        else:
            poses = rec["trajectory"]["poses_world"]
            believed = rec["trajectory"].get("poses_estimate_world")
            if believed:
                td.draw_path(believed, (255, 140, 0))
                gap = max(math.hypot(a[0] - b[0], a[1] - b[1]) for a, b in zip(poses, believed))
                title += f" | believed path (orange): up to {gap:.2f} m off"
            td.draw_path(poses)
            x, y, yaw = poses[-1]
            td.draw_pose(x, y, yaw, (0, 90, 230), "stop")
            title += f" | {rec.get('agent')}: {'success' if rec['success'] else 'failure'}, SPL {rec['spl']:.2f}, {rec['steps']} steps"
    td.text(title, (td.home.bounds_m[0], td.home.bounds_m[3] + 0.3), (0, 0, 0), 0.45)
    return td.rgb()


def _find_record(eval_dir: Path, episode_id: str) -> dict | None:
    path = eval_dir / "episodes.jsonl"
    if not path.exists():
        return None
    for line in path.read_text().splitlines():
        try:
            rec = json.loads(line)
        except json.JSONDecodeError:
            continue
        if rec.get("episode_id") == episode_id:
            return rec
    return None


def run(args: argparse.Namespace) -> int:
    from sim.show import TopDown, goal_sheet

    out = Path(args.out)
    if args.scene is None and args.episodes is None:
        log.error("give --scene SEED or --episodes DIR")
        return 2
    if args.scene is not None:
        from sim.scene_gen import generate_home

        home = generate_home(args.scene)
        _save(out / f"map-{args.scene}.png", TopDown(home).draw_home().rgb())
        if args.gallery:
            import numpy as np
            from tqdm import tqdm

            from sim.goals import sample_goal_images
            from sim.world import SimWorld

            tiles = []
            with SimWorld(home) as world:
                for inst in tqdm(home.instances[: args.limit], desc="gallery", unit="instance"):
                    imgs = sample_goal_images(world, inst.object_id, 1, seed=(args.scene % 2**31, inst.object_id))
                    for g in imgs:
                        tiles.append((f"{inst.object_id}: {inst.category} ({inst.variant})", g.rgb))
                    if not imgs:
                        log.warning("instance %d (%s): no acceptable goal image", inst.object_id, inst.category)
            _save(
                out / f"gallery-{args.scene}.png", goal_sheet(tiles) if tiles else np.full((64, 64, 3), 255, np.uint8)
            )
    if args.episodes is not None:
        from sim.episodes import load_episode_set

        es = load_episode_set(args.episodes)
        if args.episode:
            try:
                episode = es.by_id(args.episode)
            except KeyError as exc:
                log.error("%s", exc)
                return 2
            _save(out / f"map-{episode.episode_id}.png", _episode_map(es, episode, args.eval))
            _save(out / f"goal-{episode.episode_id}.png", es.load_goal_image(episode))
        else:
            chosen = es.episodes[: args.limit]
            tiles = [
                (f"{e.episode_id} {e.goal_category} {e.geodesic_distance_m:.1f}m", es.load_goal_image(e))
                for e in chosen
            ]
            _save(out / "goals.png", goal_sheet(tiles))
            scenes: dict[int, list] = {}
            for e in chosen:
                scenes.setdefault(e.scene_seed, []).append(e)
            for seed, eps in list(scenes.items())[: args.limit]:
                from sim.scene_gen import generate_home

                td = TopDown(generate_home(seed)).draw_home()
                for e in eps:
                    p = e.start_pose_world
                    td.draw_pose(p.x_m, p.y_m, p.yaw_rad, (220, 0, 0), e.episode_id.rsplit("-", 1)[-1])
                _save(out / f"map-{seed}.png", td.rgb())
    return 0
