"""``imgnav episodes``: generate an InstanceImageNav episode set (JSON plus PNG goal images).

imgnav episodes --split val --seed 0 --count 60 --out data/episodes/val
imgnav episodes --split val --seed 0 --count 30 --goals 4 --out data/episodes/val-goals4   # 30 sequences of 4 goals
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
    parser.add_argument(
        "--per-scene",
        type=int,
        default=None,
        help="episodes per generated home (default 5; with --goals N > 1, sequences per home, default 1)",
    )
    parser.add_argument(
        "--goals",
        type=int,
        default=1,
        help="goals per episode: N > 1 makes sequences of N goals in one home, each starting where the last ended",
    )
    parser.add_argument("--workers", type=int, default=1, help="parallel processes (the result does not depend on it)")


def run(args: argparse.Namespace) -> int:
    from sim.episode_gen import EpisodeGenConfig, generate_episode_set

    multi = args.goals > 1
    per_scene = args.per_scene if args.per_scene is not None else (1 if multi else 5)
    if args.count <= 0 or per_scene <= 0 or args.workers <= 0 or args.goals <= 0:
        log.error("--count, --per-scene, --goals and --workers must be positive")
        return 2
    if multi:
        return _run_sequences(args, per_scene)
    t0 = time.perf_counter()
    cfg = EpisodeGenConfig(episodes_per_scene=per_scene)
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


def _run_sequences(args: argparse.Namespace, per_scene: int) -> int:
    from collections import Counter

    from sim.sequence_gen import SequenceGenConfig, generate_sequence_set

    t0 = time.perf_counter()
    cfg = SequenceGenConfig(goals=args.goals, sequences_per_scene=per_scene)
    sequences = generate_sequence_set(args.split, args.seed, args.count, args.out, cfg, workers=args.workers)
    kinds = Counter(g.kind for s in sequences for g in s.goals[1:])
    log.info(
        "wrote %d sequences of %d goals to %s in %.1f s (later goals: %s)",
        len(sequences),
        args.goals,
        args.out,
        time.perf_counter() - t0,
        ", ".join(f"{k}: {n}" for k, n in sorted(kinds.items())),
    )
    return 0
