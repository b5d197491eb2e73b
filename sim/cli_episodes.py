"""``imgnav episodes``: generate an InstanceImageNav episode set (JSON plus PNG goal images).

imgnav episodes --split val --seed 0 --count 60 --out data/episodes/val
"""

from __future__ import annotations

import argparse
import logging
import time

from sim.episodes import SPLITS

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--split", choices=SPLITS, required=True, help="scene-seed range (disjoint per split)")
    parser.add_argument("--seed", type=int, default=0, help="set seed: the same seed gives identical episodes")
    parser.add_argument("--count", type=int, required=True, help="number of episodes")
    parser.add_argument("--out", required=True, help="output directory (episodes.json, goals/*.png)")
    parser.add_argument("--per-scene", type=int, default=5, help="episodes per generated home")
    parser.add_argument("--workers", type=int, default=1, help="parallel processes (the result does not depend on it)")


def run(args: argparse.Namespace) -> int:
    from sim.episode_gen import EpisodeGenConfig, generate_episode_set

    if args.count <= 0 or args.per_scene <= 0 or args.workers <= 0:
        log.error("--count, --per-scene and --workers must be positive")
        return 2
    t0 = time.perf_counter()
    cfg = EpisodeGenConfig(episodes_per_scene=args.per_scene)
    episodes = generate_episode_set(args.split, args.seed, args.count, args.out, cfg, workers=args.workers)
    cats: dict[str, int] = {}
    for e in episodes:
        cats[e.goal_category] = cats.get(e.goal_category, 0) + 1
    log.info(
        "wrote %d episodes to %s in %.1f s (%s)",
        len(episodes),
        args.out,
        time.perf_counter() - t0,
        ", ".join(f"{c}: {n}" for c, n in sorted(cats.items())),
    )
    return 0
