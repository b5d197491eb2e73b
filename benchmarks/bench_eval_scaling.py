"""Evaluation throughput: the runner's scheduling before and after issue 32, or local worker
processes against Ray on the same machine and the hours 1,000 episodes would take on N such
machines.

    .venv/bin/python benchmarks/bench_eval_scaling.py --episodes data/episodes/val30 --limit 8 --agent oracle
    .venv/bin/python benchmarks/bench_eval_scaling.py --compare ray [--episodes DIR] [--limit 20] [--agent modiin]

``--compare schedule`` (the default): on the same first ``--limit`` episodes, back to back,
``imgnav eval --workers CPUS`` with the old scheduling (whole homes, most episodes first, the
set's order otherwise: ``schedule.OLD_POLICY``) and with the current one (episodes handed out
as workers become free, homes longest first, a large home split across workers). Prints, from
each run's ``summary.json`` ``throughput``: wall time, CPU time of the processes, episodes per
CPU-hour, per wall-hour and per core-hour (CPUS x wall), the workers' busy share (episode wall
time over CPUS x wall), home builds, worker start-up and the idle tail; and whether the records
are identical apart from timings. Then both policies replayed on CPUS idle cores from the CPU
seconds the current run recorded (each episode's ``cpu_s``, each home's
``scene_build_cpu_s``; ``schedule.replay``): on a shared, loaded machine a worker left alone
runs faster, so measured wall times understate what an idle tail costs, and the replay shows
the scheduling alone. With ``--agent oracle`` (cheap) the figures show the scheduling, not the
agent; ``--repeat R`` alternates the order over R rounds.

``--compare ray``: on the same first ``--limit`` episodes, back to back: ``imgnav eval --workers CPUS`` and
``imgnav eval --ray local --workers CPUS`` (Ray started here with CPUS CPUs; its start-up is
timed on its own; ``--repeat R`` alternates the order over R rounds and averages). Prints
episodes per hour of each, the ratio ray/local (target >= 0.9),
whether the per-episode records agree (metrics, steps, stop reason), the cost of one
episode in CPU-seconds (wall x CPUs / episodes, from the Ray run) and the hours for 1,000
episodes on N machines of CPUS cores (cost x 1000 / (N x CPUS), plus one Ray start-up;
it ignores the tail where fewer homes than CPUs are left). Without ``--episodes``, a val
set of ``--limit`` episodes (seed 0) is generated into a temporary directory first.
Timings from a loaded machine are not final: run it on a quiet one.

``--compare code --before REV``: the agent of another commit against the code here, on the same
first ``--limit`` episodes, back to back (``--repeat R`` alternates the order). Each side is one
``imgnav eval --workers CPUS`` process: REV's from a git worktree made for it (removed after), the
current one from this checkout; the CPU of each is that process's and its workers' (the
children's ``getrusage``, taken around it), so the figure does not depend on what the commit
records. Prints episodes per CPU-hour and their ratio, SR, SPL and steps, and the parts of a
step from the records (medians over episodes of the agent's per-part medians:
extraction, the gate's first stage, LighterGlue (the exit stage's layers, or all), mapping,
alignment, planning, the agent's whole step; and the simulator's step). Steps differ when the
two agents act differently: the CPU per step is printed beside the CPU per episode.
"""

from __future__ import annotations

import argparse
import json
import logging
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

SAME_FIELDS = ("success", "spl", "ne", "steps", "path_length_m", "stop_reason", "called_stop", "max_steps_reached")


def _eval(
    ep_dir: str, agent: str, cpus: int, limit: int, out: Path, extra: list[str], ray_options=None, policy=None
) -> tuple[float, list[dict], dict]:
    """One ``imgnav eval`` run: its wall seconds, records and summary."""
    from sim.evaluation.cli import add_arguments
    from sim.evaluation.runner import read_records, run_evaluation
    from sim.evaluation.schedule import DEFAULT_POLICY

    parser = argparse.ArgumentParser()
    add_arguments(parser)
    args = parser.parse_args(
        ["--episodes", ep_dir, "--agent", agent, "--out", str(out), "--workers", str(cpus), *extra]
    )
    t0 = time.perf_counter()
    summary = run_evaluation(
        ep_dir,
        agent,
        args,
        out,
        limit=limit,
        workers=cpus,
        progress=False,
        ray=ray_options,
        policy=policy or DEFAULT_POLICY,
    )
    return time.perf_counter() - t0, read_records(out), summary


THROUGHPUT_ROWS = (
    ("wall (s)", "wall_s", "{:.1f}"),
    ("CPU of the processes (s)", "cpu_s", "{:.1f}"),
    ("episodes' own wall (s)", "episode_wall_s", "{:.1f}"),
    ("episodes per CPU-hour", "episodes_per_cpu_hour", "{:.1f}"),
    ("episodes per wall-hour", "episodes_per_wall_hour", "{:.1f}"),
    ("episodes per core-hour", "episodes_per_core_hour", "{:.1f}"),
    ("busy share", "busy_share", "{:.3f}"),
    ("home builds", "scene_builds", "{:.0f}"),
    ("home build (s, summed)", "scene_build_s", "{:.1f}"),
    ("worker start-up (s, summed)", "worker_start_s", "{:.1f}"),
    ("idle tail (s, summed over workers)", "tail_idle_s", "{:.1f}"),
)


def _mean(xs: list) -> float:
    xs = [float(x) for x in xs if x is not None]
    return sum(xs) / len(xs) if xs else float("nan")


def compare_schedules(args: argparse.Namespace, ep_dir: str, runs: Path, extra: list[str]) -> dict:
    """Old and current scheduling back to back (module docstring); prints the table, returns the figures."""
    from sim.evaluation.compare import identical
    from sim.evaluation.schedule import DEFAULT_POLICY, OLD_POLICY

    policies = {"before": OLD_POLICY, "after": DEFAULT_POLICY}
    results: dict[str, list[dict]] = {"before": [], "after": []}
    for r in range(args.repeat):
        order = ["before", "after"] if r % 2 == 0 else ["after", "before"]
        for name in order:
            _, _, summary = _eval(
                ep_dir, args.agent, args.cpus, args.limit, runs / f"{name}{r}", extra, policy=policies[name]
            )
            results[name].append(summary["throughput"])
    same, diffs = identical(str(runs / "before0"), str(runs / "after0"))
    fig = {
        name: {key: _mean([t.get(key) for t in ts]) for _, key, _ in THROUGHPUT_ROWS} for name, ts in results.items()
    }
    n = results["after"][0]["episodes"]
    print(
        f"{args.agent} {args.eval_args} on {n} episodes of {ep_dir}, --workers {args.cpus}, old and current "
        f"scheduling back to back, {args.repeat} round(s) in alternating order (means)"
    )
    print("| figure | before (whole homes, most episodes first) | after (longest first, homes split) |")
    print("| --- | ---: | ---: |")
    for label, key, fmt in THROUGHPUT_ROWS:
        print(f"| {label} | {fmt.format(fig['before'][key])} | {fmt.format(fig['after'][key])} |")
    print(f"records identical apart from timings: {same - len({d.split(':')[0] for d in diffs})}/{same}")
    for d in diffs[:5]:
        print("  ", d)
    replayed = replay_schedules(ep_dir, args.limit, runs / "after0", args.cpus)
    print(f"\nreplayed on {args.cpus} idle cores from the recorded CPU seconds (start-up left out):")
    print("| figure | before | after |")
    print("| --- | ---: | ---: |")
    for key, fmt in (
        ("makespan_s", "{:.1f}"),
        ("units_per_core_hour", "{:.1f}"),
        ("busy_share", "{:.3f}"),
        ("scene_builds", "{:.0f}"),
        ("tail_idle_s", "{:.1f}"),
    ):
        print(f"| {key} | {fmt.format(replayed['before'][key])} | {fmt.format(replayed['after'][key])} |")
    return {
        "compare": "schedule",
        "agent": args.agent,
        "eval_args": args.eval_args,
        "episodes": n,
        "episode_set": ep_dir,
        "cpus": args.cpus,
        "repeat": args.repeat,
        "before": fig["before"],
        "after": fig["after"],
        "records_identical": f"{same - len({d.split(':')[0] for d in diffs})}/{same}",
        "replayed_on_idle_cores": replayed,
    }


# the parts of a step: (label, where in a record); the agent's are medians over its steps
STEP_PARTS = (
    ("extract", ("modiin", "median_ms", "reid_extract")),
    ("gate (first stage)", ("modiin", "median_ms", "reid_gate")),
    ("match (LighterGlue)", ("modiin", "median_ms", "reid_match")),
    ("mapping", ("modiin", "median_ms", "mapping")),
    ("alignment", ("modiin", "median_ms", "align")),
    ("planning", ("modiin", "median_ms", "planning")),
    ("agent step", ("modiin", "median_ms", "total")),
    ("simulator step", ("timing", "sim_ms_per_step")),
)


def _field(record: dict, path: tuple[str, ...]) -> float | None:
    for key in path:
        if not isinstance(record, dict) or key not in record:
            return None
        record = record[key]
    return None if record is None else float(record)


def _eval_process(cwd: Path, ep_dir: str, agent: str, cpus: int, limit: int, out: Path, extra: list[str]) -> dict:
    """One ``imgnav eval`` process run from ``cwd`` (a checkout): its wall and CPU seconds (the
    process and its workers), and its records."""
    cmd = [sys.executable, "-m", "console.cli", "eval", "--episodes", str(Path(ep_dir).resolve()), "--agent", agent]
    cmd += ["--workers", str(cpus), "--limit", str(limit), "--out", str(out.resolve()), *extra]
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(cmd, cwd=cwd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    records = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines() if line.strip()]
    return {"wall_s": wall, "cpu_s": cpu, "records": records}


def compare_code(args: argparse.Namespace, ep_dir: str, runs: Path, extra: list[str]) -> dict:
    """The agent of ``--before`` against the code here, back to back (module docstring)."""
    here = Path(__file__).resolve().parents[1]
    rev = subprocess.run(
        ["git", "rev-parse", "--short", args.before], cwd=here, check=True, capture_output=True, text=True
    ).stdout.strip()
    tree = Path(tempfile.mkdtemp(prefix=f"bench-{rev}-"))
    subprocess.run(["git", "worktree", "add", "--detach", "-f", str(tree), rev], cwd=here, check=True,
                   capture_output=True)  # fmt: skip
    sides = {"before": tree, "after": here}
    runs_of: dict[str, list[dict]] = {"before": [], "after": []}
    try:
        for r in range(args.repeat):
            for name in ["before", "after"] if r % 2 == 0 else ["after", "before"]:
                out = runs / f"{name}{r}"
                runs_of[name].append(_eval_process(sides[name], ep_dir, args.agent, args.cpus, args.limit, out, extra))
    finally:
        subprocess.run(["git", "worktree", "remove", "--force", str(tree)], cwd=here, capture_output=True)
    fig: dict[str, dict] = {}
    for name, rs in runs_of.items():
        recs = rs[0]["records"]
        n = len(recs)
        cpu = statistics.median(x["cpu_s"] for x in rs)
        steps = sum(int(x["steps"]) for x in recs)
        parts = {}
        for label, path in STEP_PARTS:
            vals = [v for v in (_field(x, path) for x in recs) if v is not None]
            parts[label] = statistics.median(vals) if vals else None
        fig[name] = {
            "episodes": n,
            "cpu_s": [round(x["cpu_s"], 1) for x in rs],
            "wall_s": [round(x["wall_s"], 1) for x in rs],
            "episodes_per_cpu_hour": 3600.0 * n / cpu,
            "cpu_ms_per_step": 1000.0 * cpu / max(steps, 1),
            "steps": steps,
            "sr": sum(bool(x["success"]) for x in recs) / max(n, 1),
            "spl": sum(float(x["spl"]) for x in recs) / max(n, 1),
            "parts_ms": parts,
        }
    b, a = fig["before"], fig["after"]
    print(
        f"{args.agent} {args.eval_args} on {a['episodes']} episodes of {ep_dir}, --workers {args.cpus}: {rev} "
        f"(before) against this checkout (after), back to back, {args.repeat} round(s) in alternating order "
        "(CPU: median over rounds; parts: medians over episodes of the first round)"
    )
    print(f"| figure | before ({rev}) | after | after / before |")
    print("| --- | ---: | ---: | ---: |")
    for label, key, fmt in (
        ("episodes per CPU-hour", "episodes_per_cpu_hour", "{:.1f}"),
        ("CPU ms per step", "cpu_ms_per_step", "{:.1f}"),
        ("steps", "steps", "{:.0f}"),
        ("SR", "sr", "{:.3f}"),
        ("SPL", "spl", "{:.3f}"),
    ):
        print(f"| {label} | {fmt.format(b[key])} | {fmt.format(a[key])} | {a[key] / b[key]:.2f} |")
    for label, _ in STEP_PARTS:
        pb, pa = b["parts_ms"][label], a["parts_ms"][label]
        ratio = f"{pa / pb:.2f}" if pb and pa is not None else ""
        cell = lambda v: "" if v is None else f"{v:.1f}"  # noqa: E731
        print(f"| {label} (ms, median) | {cell(pb)} | {cell(pa)} | {ratio} |")
    print(f"CPU per round (s): before {b['cpu_s']}, after {a['cpu_s']}")
    return {"compare": "code", "before_rev": rev, "agent": args.agent, "eval_args": args.eval_args,
            "episode_set": ep_dir, "cpus": args.cpus, "repeat": args.repeat, **fig}  # fmt: skip


def replay_schedules(ep_dir: str, limit: int, run: Path, cpus: int) -> dict[str, dict]:
    """Old and current scheduling replayed from one run's recorded CPU seconds."""
    import statistics

    from sim.evaluation.runner import read_records
    from sim.evaluation.schedule import DEFAULT_POLICY, OLD_POLICY, replay, units_of
    from sim.sequences import load_any_set

    records = read_records(run)
    units = units_of(load_any_set(ep_dir).episodes[:limit])
    unit_s = {r["episode_id"]: float(r["timing"]["cpu_s"]) for r in records}
    builds: dict[int, list[float]] = {}
    for r in records:
        builds.setdefault(r["scene_seed"], []).append(float(r["timing"]["scene_build_cpu_s"]))
    build_s = {seed: statistics.median(xs) for seed, xs in builds.items()}
    return {
        "before": replay(units, unit_s, build_s, cpus, OLD_POLICY),
        "after": replay(units, unit_s, build_s, cpus, DEFAULT_POLICY),
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument(
        "--compare",
        choices=["schedule", "ray", "code"],
        default="schedule",
        help="schedule: the runner's old and current scheduling; ray: local workers against Ray; "
        "code: the agent of --before against this checkout",
    )
    p.add_argument("--before", default=None, help="with --compare code: the commit to compare against")
    p.add_argument("--episodes", default=None, help="val episode set (default: generate --limit episodes)")
    p.add_argument("--limit", type=int, default=20)
    p.add_argument("--agent", default="modiin")
    p.add_argument("--cpus", type=int, default=2)
    p.add_argument("--machines", type=int, nargs="+", default=[1, 2, 5, 10, 25, 50])
    p.add_argument("--json", default=None, help="also write the figures to this file")
    p.add_argument("--eval-args", default="", help='more `imgnav eval` flags, e.g. "--modiin-set reid.gate=true"')
    p.add_argument(
        "--repeat", type=int, default=1, help="rounds (the order alternates: before/local first, then after/ray first)"
    )
    p.add_argument(
        "--keep", default=None, help="write the two runs' outputs under this directory (default: a temp dir)"
    )
    args = p.parse_args()
    logging.basicConfig(level=logging.WARNING)

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
    if args.compare in ("schedule", "code"):
        if args.compare == "code" and not args.before:
            raise SystemExit("--compare code needs --before REV")
        fig = (compare_schedules if args.compare == "schedule" else compare_code)(args, ep_dir, runs, extra)
        if args.json:
            Path(args.json).write_text(json.dumps(fig, indent=1) + "\n")
        tmp.cleanup()
        return 0

    import ray

    from sim.evaluation.ray_backend import RayOptions, connect

    summaries: dict[str, list[dict]] = {"local": [], "ray": []}

    def local_run(r: int) -> tuple[float, list[dict], float]:
        wall, recs, summary = _eval(ep_dir, args.agent, args.cpus, args.limit, runs / f"local{r}", extra)
        summaries["local"].append(summary)
        return wall, recs, 0.0

    def ray_run(r: int) -> tuple[float, list[dict], float]:
        options = RayOptions(address="local", num_cpus=args.cpus)
        t0 = time.perf_counter()
        connect(options)  # as `imgnav eval --ray local` starts it; the run below reuses it
        startup = time.perf_counter() - t0
        try:
            wall, recs, summary = _eval(ep_dir, args.agent, args.cpus, args.limit, runs / f"ray{r}", extra, options)
        finally:
            ray.shutdown()
        summaries["ray"].append(summary)
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
        "episodes_per_cpu_hour": {
            k: _mean([s["throughput"]["episodes_per_cpu_hour"] for s in v]) for k, v in summaries.items()
        },
        "busy_share": {k: _mean([s["throughput"]["busy_share"] for s in v]) for k, v in summaries.items()},
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
    print(
        "episodes per CPU-hour (local: the processes' CPU; ray: the episodes' own): "
        + ", ".join(f"{k} {v:.1f}" for k, v in fig["episodes_per_cpu_hour"].items())
        + "; busy share: "
        + ", ".join(f"{k} {v:.3f}" for k, v in fig["busy_share"].items())
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
