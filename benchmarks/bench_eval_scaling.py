"""Evaluation throughput: local worker processes against Ray on the same machine, and the
hours 1,000 episodes would take on N such machines.

    .venv/bin/python benchmarks/bench_eval_scaling.py [--episodes DIR] [--limit 20] [--agent modiin] [--cpus 2]

On the same first ``--limit`` episodes, back to back: ``imgnav eval --workers CPUS`` and
``imgnav eval --ray local --workers CPUS`` (Ray started here with CPUS CPUs; its start-up is
timed on its own; ``--repeat R`` alternates the order over R rounds and averages). Prints
episodes per hour of each, the ratio ray/local (target >= 0.9),
whether the per-episode records agree (metrics, steps, stop reason), the cost of one
episode in CPU-seconds (wall x CPUs / episodes, from the Ray run) and the hours for 1,000
episodes on N machines of CPUS cores (cost x 1000 / (N x CPUS), plus one Ray start-up;
it ignores the tail where fewer homes than CPUs are left). Without ``--episodes``, a val
set of ``--limit`` episodes (seed 0) is generated into a temporary directory first.
Timings from a loaded machine are not final: run it on a quiet one.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

SAME_FIELDS = ("success", "spl", "ne", "steps", "path_length_m", "stop_reason", "called_stop", "max_steps_reached")


def _eval(
    ep_dir: str, agent: str, cpus: int, limit: int, out: Path, extra: list[str], ray_options=None
) -> tuple[float, list[dict]]:
    from sim.evaluation.cli import add_arguments
    from sim.evaluation.runner import read_records, run_evaluation

    parser = argparse.ArgumentParser()
    add_arguments(parser)
    args = parser.parse_args(
        ["--episodes", ep_dir, "--agent", agent, "--out", str(out), "--workers", str(cpus), *extra]
    )
    t0 = time.perf_counter()
    run_evaluation(ep_dir, agent, args, out, limit=limit, workers=cpus, progress=False, ray=ray_options)
    return time.perf_counter() - t0, read_records(out)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--episodes", default=None, help="val episode set (default: generate --limit episodes)")
    p.add_argument("--limit", type=int, default=20)
    p.add_argument("--agent", default="modiin")
    p.add_argument("--cpus", type=int, default=2)
    p.add_argument("--machines", type=int, nargs="+", default=[1, 2, 5, 10, 25, 50])
    p.add_argument("--json", default=None, help="also write the figures to this file")
    p.add_argument("--eval-args", default="", help='more `imgnav eval` flags, e.g. "--modiin-set reid.gate=true"')
    p.add_argument("--repeat", type=int, default=1, help="rounds (the order alternates: local first, then ray first)")
    p.add_argument(
        "--keep", default=None, help="write the two runs' outputs under this directory (default: a temp dir)"
    )
    args = p.parse_args()
    logging.basicConfig(level=logging.WARNING)

    import ray

    from sim.evaluation.ray_backend import RayOptions, connect

    tmp = tempfile.TemporaryDirectory()
    ep_dir = args.episodes
    if ep_dir is None:
        from sim.episode_gen import generate_episode_set

        ep_dir = str(Path(tmp.name) / "episodes")
        generate_episode_set("val", 0, args.limit, ep_dir, workers=args.cpus, progress=False)

    import shlex

    extra = shlex.split(args.eval_args)
    runs = Path(args.keep) if args.keep else Path(tmp.name)
    if runs.exists() and any(runs.glob("*/episodes.jsonl")):
        raise SystemExit(f"{runs} holds earlier runs; use another --keep")

    def local_run(r: int) -> tuple[float, list[dict], float]:
        wall, recs = _eval(ep_dir, args.agent, args.cpus, args.limit, runs / f"local{r}", extra)
        return wall, recs, 0.0

    def ray_run(r: int) -> tuple[float, list[dict], float]:
        options = RayOptions(address="local", num_cpus=args.cpus)
        t0 = time.perf_counter()
        connect(options)  # as `imgnav eval --ray local` starts it; the run below reuses it
        startup = time.perf_counter() - t0
        try:
            wall, recs = _eval(ep_dir, args.agent, args.cpus, args.limit, runs / f"ray{r}", extra, options)
        finally:
            ray.shutdown()
        return wall, recs, startup

    # back to back; with --repeat the order alternates so a drifting machine load favours neither
    results: dict[str, list[tuple[float, list[dict], float]]] = {"local": [], "ray": []}
    for r in range(args.repeat):
        order = [("local", local_run), ("ray", ray_run)] if r % 2 == 0 else [("ray", ray_run), ("local", local_run)]
        for name, fn in order:
            results[name].append(fn(r))
    local_s = sum(x[0] for x in results["local"]) / args.repeat
    ray_s = sum(x[0] for x in results["ray"]) / args.repeat
    startup_s = sorted(x[2] for x in results["ray"])[args.repeat // 2]
    local_recs = results["local"][0][1]

    n = len(local_recs)
    by_id = {r["episode_id"]: r for r in local_recs}
    same = sum(
        all(r[k] == by_id[r["episode_id"]][k] for k in SAME_FIELDS)
        for run in results["local"] + results["ray"]
        for r in run[1]
        if r["episode_id"] in by_id
    )
    total = sum(len(run[1]) for run in results["local"] + results["ray"])
    eph_local, eph_ray = 3600 * n / local_s, 3600 * n / ray_s
    eph_ray_startup = 3600 * n / (ray_s + startup_s)
    cost_cpu_s = ray_s * args.cpus / n
    hours = {m: (cost_cpu_s * 1000 / (m * args.cpus) + startup_s) / 3600 for m in args.machines}
    fig = {
        "agent": args.agent,
        "eval_args": args.eval_args,
        "episodes": n,
        "episode_set": ep_dir,
        "cpus": args.cpus,
        "repeat": args.repeat,
        "local_wall_s": [round(x[0], 1) for x in results["local"]],
        "ray_wall_s": [round(x[0], 1) for x in results["ray"]],
        "ray_startup_s": [round(x[2], 2) for x in results["ray"]],
        "episodes_per_hour_local": round(eph_local, 1),
        "episodes_per_hour_ray": round(eph_ray, 1),
        "episodes_per_hour_ray_with_startup": round(eph_ray_startup, 1),
        "ratio_ray_over_local": round(eph_ray / eph_local, 3),
        "ratio_with_startup": round(eph_ray_startup / eph_local, 3),
        "records_identical": f"{same}/{total}",
        "cpu_s_per_episode": round(cost_cpu_s, 1),
        "hours_for_1000_episodes": {str(m): round(h, 2) for m, h in hours.items()},
    }
    print(
        f"{args.agent} {args.eval_args} on {n} episodes of {ep_dir}, {args.cpus} CPUs, back to back, "
        f"{args.repeat} round(s) in alternating order"
    )
    print("| run | wall per round (s) | episodes/hour (mean wall) |")
    print("| --- | --- | ---: |")
    print(f"| --workers {args.cpus} | {', '.join(f'{x[0]:.1f}' for x in results['local'])} | {eph_local:.1f} |")
    print(f"| --ray local ({args.cpus} CPUs) | {', '.join(f'{x[0]:.1f}' for x in results['ray'])} | {eph_ray:.1f} |")
    print(f"| --ray local incl. start-up | | {eph_ray_startup:.1f} |")
    print(
        f"ratio ray/local {eph_ray / eph_local:.3f} (with start-up {eph_ray_startup / eph_local:.3f}); "
        f"Ray start-up {', '.join(f'{x[2]:.2f}' for x in results['ray'])} s; "
        f"records equal to the first local run's (metrics, steps, stop reason): {same}/{total}"
    )
    print(f"cost {cost_cpu_s:.1f} CPU-s per episode; 1,000 episodes on N machines of {args.cpus} cores:")
    print("| N | hours |")
    print("| ---: | ---: |")
    for m, h in hours.items():
        print(f"| {m} | {h:.2f} |")
    if args.json:
        Path(args.json).write_text(json.dumps(fig, indent=1) + "\n")
    tmp.cleanup()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
