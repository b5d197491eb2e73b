"""``imgnav eval``: run an agent on an episode set and write metrics.

    imgnav eval --episodes data/episodes/val --agent oracle --limit 60 --workers 2 --out runs/oracle-val
    imgnav eval --episodes data/episodes/val --agent oracle --ray auto --out runs/oracle-val   # on a Ray cluster

Writes OUT/episodes.jsonl (one record per episode) and OUT/summary.json (sr, spl,
ne, max_st, episodes, per_category, ...). Re-running skips finished episodes. On a multi-goal
set (``imgnav episodes --goals N``) a record is a sequence with its subtasks and the summary
sets the first goal against the later ones (``sim.evaluation.multigoal``); ``--memory`` gives
the goals of a sequence one memory of the home.
Agents come from ``sim.evaluation.registry`` (each adds its own flags below).
"""

from __future__ import annotations

import argparse
import json
import logging
from collections.abc import Callable
from pathlib import Path

log = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from sim.evaluation.registry import all_specs

    specs = all_specs()
    parser.add_argument("--episodes", required=True, help="episode-set directory (from `imgnav episodes`)")
    parser.add_argument(
        "--agent", required=True, choices=[s.name for s in specs], help="; ".join(f"{s.name}: {s.help}" for s in specs)
    )
    parser.add_argument("--out", required=True, help="output directory (episodes.jsonl, summary.json)")
    parser.add_argument("--limit", type=int, default=None, help="only the first N episodes")
    parser.add_argument(
        "--episode-ids",
        nargs="+",
        default=None,
        metavar="ID",
        help="only these episodes (ids, or @FILE with one id per line)",
    )
    parser.add_argument("--workers", type=int, default=1, help="parallel worker processes (episodes grouped by scene)")
    parser.add_argument(
        "--subtask-budget",
        type=int,
        default=None,
        metavar="STEPS",
        help="multi-goal sets only: steps per goal of a sequence (default: the single-goal budget, 1000)",
    )
    parser.add_argument(
        "--memory",
        action="store_true",
        help="multi-goal sets, agents with a memory of a home (modiin) only: the goals of a sequence share "
        "one memory of the home (the map, keyframes of what was seen, earlier goals), in one pose frame "
        "carried from goal to goal, so a later goal is first looked for in what was seen before; each "
        "subtask's record gets the memory's figures. Off (default): every goal starts from nothing",
    )
    parser.add_argument("--overwrite", action="store_true", help="discard earlier results in --out instead of resuming")
    parser.add_argument(
        "--fail-fast", action="store_true", help="stop at the first episode error instead of recording it"
    )
    add_realism_arguments(parser)
    add_ray_arguments(parser)
    for spec in specs:
        if spec.add_arguments:
            spec.add_arguments(parser.add_argument_group(f"{spec.name} agent"))


def add_realism_arguments(parser: argparse.ArgumentParser, realism_help: str | None = None) -> None:
    """``--realism`` and its options (``imgnav eval``, ``imgnav console`` and ``imgnav calibrate``,
    which says what the profile does there in ``realism_help``; sim/realism.py)."""
    from sim.realism import COMPONENTS, PROFILES

    g = parser.add_argument_group("realism (a real Stretch's senses and motion; docs/realism.md)")
    g.add_argument(
        "--realism",
        default="clean",
        choices=list(PROFILES),
        help=realism_help or "noise profile of the simulated robot: clean (exact, the headline) or stretch",
    )
    g.add_argument(
        "--realism-only",
        nargs="+",
        default=None,
        choices=list(COMPONENTS),
        metavar="PART",
        help=f"only these components of the profile (the others exact): {', '.join(COMPONENTS)}",
    )
    g.add_argument("--realism-seed", type=int, default=0, help="seed of the noise (with the episode id)")


def realism_of(args: argparse.Namespace):
    """The ``Realism`` of the parsed flags (None: exact, the clean profile)."""
    from sim.realism import Realism, get_profile

    profile = get_profile(getattr(args, "realism", "clean") or "clean", getattr(args, "realism_only", None))
    return None if profile.clean else Realism(profile, int(getattr(args, "realism_seed", 0) or 0))


def add_ray_arguments(parser: argparse.ArgumentParser) -> None:
    """``--ray`` and its options (``imgnav eval`` and ``imgnav calibrate``)."""
    g = parser.add_argument_group("Ray (evaluation across machines; README 'Evaluating on a cluster')")
    g.add_argument(
        "--ray",
        default=None,
        metavar="ADDRESS",
        help="run the work as Ray tasks: 'local' (Ray on this machine with --workers CPUs), 'auto' "
        "(the cluster this machine is a node of), or the head's HOST:PORT (or ray://HOST:10001)",
    )
    g.add_argument(
        "--ray-retries",
        type=int,
        default=2,
        help="re-submissions of a task whose worker or node died (then its episodes are recorded as errors)",
    )
    g.add_argument(
        "--ray-max-in-flight",
        type=int,
        default=None,
        help="tasks submitted at once (default: twice the cluster's CPUs)",
    )
    g.add_argument(
        "--ray-runtime-env",
        default=None,
        metavar="JSON",
        help='Ray runtime environment for the tasks, e.g. \'{"working_dir": "."}\' to ship this checkout '
        "to nodes that have the dependencies but not the code",
    )


def ray_options(args: argparse.Namespace, num_cpus: int):
    """The ``RayOptions`` of the parsed flags, or None without ``--ray``."""
    if not getattr(args, "ray", None):
        return None
    from sim.evaluation.ray_backend import RayOptions

    env = None
    if getattr(args, "ray_runtime_env", None):
        try:
            env = json.loads(args.ray_runtime_env)
        except json.JSONDecodeError as exc:
            raise ValueError(f"--ray-runtime-env is not JSON: {exc}") from exc
        if not isinstance(env, dict):
            raise ValueError("--ray-runtime-env must be a JSON object")
    return RayOptions(
        address=args.ray,
        num_cpus=num_cpus,
        max_retries=max(0, args.ray_retries),
        max_in_flight=args.ray_max_in_flight,
        runtime_env=env,
    )


def episode_ids(items: list[str] | None) -> list[str] | None:
    """``--episode-ids`` values: ids, or ``@FILE`` naming a file of ids (one per line, # comments)."""
    if items is None:
        return None
    out: list[str] = []
    for item in items:
        if item.startswith("@"):
            lines = Path(item[1:]).read_text().splitlines()
            out += [ln.split("#", 1)[0].strip() for ln in lines if ln.split("#", 1)[0].strip()]
        else:
            out += [s for s in item.split(",") if s]
    if not out:
        raise ValueError("--episode-ids names no episode")
    return out


def run(args: argparse.Namespace) -> int:
    from sim.evaluation.runner import RECORDS, SUMMARY, run_evaluation

    out = Path(args.out)
    if args.overwrite:
        for name in (RECORDS, SUMMARY):
            (out / name).unlink(missing_ok=True)
    if args.limit is not None and args.limit <= 0:
        log.error("--limit must be positive")
        return 2
    try:
        ray = ray_options(args, args.workers)
        summary = run_evaluation(
            args.episodes,
            args.agent,
            args,
            out,
            limit=args.limit,
            workers=args.workers,
            fail_fast=args.fail_fast,
            ray=ray,
            episode_ids=episode_ids(args.episode_ids),
        )
    except (FileNotFoundError, ValueError) as exc:
        log.error("%s", exc)
        return 2
    except KeyboardInterrupt:
        log.warning("interrupted: the finished episodes are in %s; run the same command again to resume", out / RECORDS)
        return 130
    brief = {k: summary[k] for k in ("sequences", "episodes", "sr", "spl", "ne", "max_st", "errors") if k in summary}
    log.info("%s on %s: %s", args.agent, args.episodes, json.dumps(brief))
    log.info("wrote %s and %s", out / RECORDS, out / SUMMARY)
    return 0


def tables_main(render: Callable[[list[str]], str], out_dirs: list[str]) -> int:
    """Print the comparison tables ``render`` makes of several ``imgnav eval`` outputs
    (``python -m sim.evaluation.modiin OUT1 OUT2 ...``)."""
    print(render(out_dirs))
    return 0
