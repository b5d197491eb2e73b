"""Evaluation: run an agent on an episode set and write per-episode records and a summary.

Outputs (``OUT``)::

    OUT/episodes.jsonl   one JSON record per finished episode (appended as they finish, so
                         their order depends on the workers; nothing reads it by position)
    OUT/summary.json     sr, spl, ne, max_st, episodes, per_category, errors, timing,
                         throughput, agent extras

Re-running with the same OUT skips the episodes already in ``episodes.jsonl`` (a
torn last line from a crash is dropped), so an interrupted run resumes.
A worker keeps the home it built for its next episode of that home. Episodes are handed out
one at a time as workers become free (``sim.evaluation.schedule``): homes longest first by an
estimate from the episode data, a worker staying in its home while it has episodes, and a free
worker joining another's home when no other home is left, so both cores are busy to the end.
With ``workers > 1`` the workers are processes (spawned, so torch and PyBullet state are never
forked); with ``ray=RayOptions(...)`` (``--ray``) each home is a Ray task on a cluster
(``sim.evaluation.ray_backend``), homes longest first. Records are the same either way.

Throughput (``summary.json`` ``throughput``, ``schedule.throughput``) covers the episodes run
by this invocation: its wall time, the CPU time of its processes (``getrusage``: the runner and
its workers, with start-up and home builds; Ray: the episodes' own), episodes per CPU-hour, per
wall-hour and per core-hour (workers x wall), the workers' busy share (episode wall time over
workers x wall), home builds, worker start-up and the idle tail. A resumed run's figures are
those of the episodes run after resuming (earlier invocations' wall and CPU are not known); an
invocation that finds nothing to run keeps the block it finds (marked
``kept_from_earlier_invocation``). Each record's ``timing`` has ``wall_s`` and ``cpu_s``, and
``summary.timing.cpu_s_per_episode`` is their mean over all records.

Adding an agent (e.g. ``--agent modiin``)
-----------------------------------------
Write ``sim/evaluation/modiin.py`` (already listed in ``registry.PLUGIN_MODULES``)::

    from sim.evaluation.registry import AgentSpec, register

    def add_arguments(group):            # flags of this agent only
        group.add_argument("--modiin-variant", default="default")
        group.add_argument("--modiin-config", default=None)

    def make_agent(args, oracle):        # oracle: the episode's SimOracle
        return ModIINAgent(...)          # default agents ignore the oracle

    class Attribution:                   # optional, one per episode
        def __init__(self, args, episode, oracle): ...
        def on_step(self, obs, action, record): ...   # record = agent.last_record
        def finish(self, episode_record): return {"failure_cause": "..."}

    def summarize(records): return {"failure_causes": {...}}

    register(AgentSpec("modiin", "the Mod-IIN agent", make_agent, add_arguments,
                       make_observer=Attribution, summarize=summarize))

``make_observer(args, episode, oracle)`` may return None. Its ``on_step`` runs after
each ``agent.act`` (before the action is applied) with the observation, the action
and ``agent.last_record``; ``finish`` gets the episode record (metrics, trajectory,
stop reason) and returns fields merged into it. ``summarize`` gets every record of
the run and returns fields merged into summary.json.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import math
import time
import traceback
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from agent.loop import LoopError, LoopStep, run_loop
from agent.types import Agent
from sim.backend import SimBackend
from sim.episodes import Episode, EpisodeSet, r4
from sim.evaluation.cli import realism_of
from sim.evaluation.registry import AgentSpec, get_spec
from sim.evaluation.schedule import DEFAULT_POLICY, Schedule, SchedulePolicy, throughput, units_of
from sim.evaluation.workers import RunStats, cpu_seconds, run_here, run_workers
from sim.metrics import aggregate
from sim.sequences import SequenceEpisode, SequenceSet, load_any_set
from sim.world import SimWorld

if TYPE_CHECKING:
    from sim.evaluation.ray_backend import RayOptions

log = logging.getLogger(__name__)

RECORDS = "episodes.jsonl"
SUMMARY = "summary.json"


def _json_safe(v: Any) -> Any:
    if isinstance(v, float) and not math.isfinite(v):
        return None if math.isnan(v) else ("inf" if v > 0 else "-inf")
    if isinstance(v, dict):
        return {k: _json_safe(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_json_safe(x) for x in v]
    return v


class _ObserverSink:
    """The agent's observer sees each step before the backend moves on (its oracle reads the
    ground truth of the frame the agent acted on)."""

    def __init__(self, observer: Any) -> None:
        self.observer = observer

    def before_apply(self, s: LoopStep) -> None:
        self.observer.on_step(s.obs, s.action, s.record)

    def step(self, s: LoopStep) -> None:
        pass


def run_episode(
    world: SimWorld,
    goal_image: EpisodeSet | np.ndarray | str | Path,
    episode: Episode,
    spec: AgentSpec,
    args: argparse.Namespace,
    fail_fast: bool = False,
) -> dict[str, Any]:
    """Run one episode in an already built world; returns its record.

    goal_image: the episode's goal image ((H, W, 3) uint8 RGB), its PNG path, or the episode set it is in."""
    t0, c0 = time.perf_counter(), time.process_time()
    if isinstance(goal_image, EpisodeSet):
        goal_image = goal_image.goal_image_path(episode)
    backend = SimBackend.for_episode(world, episode, goal_image, realism=realism_of(args))
    record, _ = run_on_backend(
        backend, episode, spec, args, lambda oracle: spec.make_agent(args, oracle), fail_fast, t0, c0
    )
    return record


def run_on_backend(
    backend: SimBackend,
    episode: Episode,
    spec: AgentSpec,
    args: argparse.Namespace,
    make_agent: Callable[[Any], Agent],
    fail_fast: bool = False,
    t0: float | None = None,
    c0: float | None = None,
    sinks: Sequence[Any] = (),
) -> tuple[dict[str, Any], Agent | None]:
    """Run the agent ``make_agent(backend.oracle)`` on a built backend to the end of ``episode``
    (the backend's episode: one single-goal episode, or one subtask of a sequence) with the
    spec's observer; returns the record and the agent (None if making it failed). Closes the
    backend (its final pose stays readable). ``t0``, ``c0``: when the episode began, by
    ``time.perf_counter`` and ``time.process_time`` (default: now); the record's ``timing``
    holds the wall and CPU seconds since (``wall_s``, ``cpu_s``: the worker process's CPU,
    all its threads). ``sinks``: more step sinks for the loop (``agent.loop``; a tracing tool's)."""
    t0 = time.perf_counter() if t0 is None else t0
    c0 = time.process_time() if c0 is None else c0
    realism = backend.realism
    agent_s = sim_s = 0.0
    error = None
    observer = None
    agent = None
    try:
        agent = make_agent(backend.oracle)
        observer = spec.make_observer(args, episode, backend.oracle) if spec.make_observer else None
        sinks = ((_ObserverSink(observer),) if observer is not None else ()) + tuple(sinks)
        try:
            # the project's one loop; the episode ends when the backend says so (STOP or budget)
            result = run_loop(backend, agent, backend.max_steps, sinks, should_stop=lambda: backend.done)
        except LoopError as exc:
            agent_s, sim_s = exc.result.act_s, exc.result.backend_s
            raise exc.cause from None
        agent_s, sim_s = result.act_s, result.backend_s
    except Exception as exc:  # agent or backend failure: recorded, counted as a failure, logged
        if fail_fast:
            raise
        error = f"{type(exc).__name__}: {exc}"
        log.error("episode %s failed: %s\n%s", episode.episode_id, error, traceback.format_exc())
        if not backend.done:
            backend.done = True
            backend.stop_reason = "error"
    m = backend.result()
    assert m is not None
    steps = max(backend.steps, 1)
    record: dict[str, Any] = {
        "episode_id": episode.episode_id,
        "scene_seed": episode.scene_seed,
        "category": episode.goal_category,
        "agent": spec.name,
        "success": m.success,
        "spl": r4(m.spl),
        "ne": r4(m.ne_m) if math.isfinite(m.ne_m) else math.inf,
        "steps": m.steps,
        "path_length_m": r4(m.path_length_m),
        "shortest_path_m": r4(m.shortest_path_m),
        "max_steps_reached": m.max_steps_reached,
        "called_stop": m.called_stop,
        "stop_reason": backend.stop_reason,
        "stop_to_viewpoint_m": r4(m.stop_to_viewpoint_m),
        "difficulty": episode.info.get("difficulty"),
        "trajectory": {
            "poses_world": [[r4(p.x_m), r4(p.y_m), r4(p.yaw_rad)] for p in backend.trajectory_world],
            "actions": [int(a) for a in backend.actions],
        },
        "timing": {
            "wall_s": r4(time.perf_counter() - t0),
            "cpu_s": r4(time.process_time() - c0),
            "agent_ms_per_step": r4(1000 * agent_s / steps),
            "sim_ms_per_step": r4(1000 * sim_s / steps),
        },
        "error": error,
    }
    if realism is not None:
        record["realism"] = realism.describe()
        record["trajectory"]["poses_estimate_world"] = [
            [r4(p.x_m), r4(p.y_m), r4(p.yaw_rad)] for p in backend.estimate_trajectory_world
        ]
    if observer is not None and error is None:
        record.update(dict(observer.finish(record)))
    backend.close()
    return record, agent


def _clean_args(args: argparse.Namespace) -> argparse.Namespace:
    return argparse.Namespace(**{k: v for k, v in vars(args).items() if not k.startswith("_")})


def run_scene(
    episodes: list[Episode],
    goal_images: Sequence[np.ndarray | str | Path],
    agent: str,
    args: argparse.Namespace,
    fail_fast: bool = False,
) -> Iterator[dict[str, Any]]:
    """Run episodes of one home (built once) in order, yielding each record as it finishes.

    The work unit of Ray tasks (local workers run one episode at a time: ``run_unit``)."""
    spec = get_spec(agent)
    t0, c0 = time.perf_counter(), time.process_time()
    world = SimWorld.from_seed(episodes[0].scene_seed)
    build_s, build_cpu_s = time.perf_counter() - t0, time.process_time() - c0
    try:
        for e, goal in zip(episodes, goal_images, strict=True):
            rec = run_episode(world, goal, e, spec, args, fail_fast)
            rec["timing"]["scene_build_s"] = r4(build_s)
            rec["timing"]["scene_build_cpu_s"] = r4(build_cpu_s)
            yield rec
    finally:
        world.close()


def error_record(episode: Episode, agent: str, error: str) -> dict[str, Any]:
    """The record of an episode that never ran to its end because its worker kept dying
    (Ray retries exhausted): scored as a failure where it started, with ``error`` set, as
    ``run_episode`` records an agent or backend exception."""
    from agent.types import MAX_STEPS
    from sim.metrics import episode_metrics

    p = episode.start_pose_world
    m = episode_metrics(
        called_stop=False,
        stop_xy_m=(p.x_m, p.y_m),
        viewpoints_xy_m=episode.viewpoints_array(),
        steps=0,
        max_steps=MAX_STEPS,
        path_length_m=0.0,
        shortest_path_m=episode.geodesic_distance_m,
        stop_geodesic_m=episode.geodesic_distance_m,
    )
    return {
        "episode_id": episode.episode_id,
        "scene_seed": episode.scene_seed,
        "category": episode.goal_category,
        "agent": agent,
        "success": m.success,
        "spl": r4(m.spl),
        "ne": r4(m.ne_m),
        "steps": 0,
        "path_length_m": 0.0,
        "shortest_path_m": r4(m.shortest_path_m),
        "max_steps_reached": False,
        "called_stop": False,
        "stop_reason": "error",
        "stop_to_viewpoint_m": r4(m.stop_to_viewpoint_m),
        "difficulty": episode.info.get("difficulty"),
        "trajectory": {"poses_world": [[r4(p.x_m), r4(p.y_m), r4(p.yaw_rad)]], "actions": []},
        "timing": {"wall_s": 0.0, "agent_ms_per_step": 0.0, "sim_ms_per_step": 0.0},
        "error": error,
    }


def _cpu_per_record(records: Sequence[dict[str, Any]], unit: str) -> dict[str, Any]:
    """The mean CPU seconds per episode (sequence) over every record that has them (records from
    before issue 32 have none)."""
    cpu = [float(r["timing"]["cpu_s"]) for r in records if "cpu_s" in r["timing"]]
    return {f"cpu_s_per_{unit}": r4(sum(cpu) / len(cpu)) if cpu else None}


def _throughput_block(out: Path, ran: Sequence[dict[str, Any]], wall_s: float, stats: RunStats) -> dict[str, Any]:
    """summary.json's ``throughput``: of this invocation's episodes; when it ran none (everything
    was done), the block the summary already had, which is the last invocation's that ran some."""
    if not ran:
        with contextlib.suppress(FileNotFoundError, json.JSONDecodeError, AttributeError):
            previous = json.loads((out / SUMMARY).read_text()).get("throughput")
            if previous:
                return {**previous, "kept_from_earlier_invocation": True}
    return throughput(
        ran,
        workers=stats.workers,
        wall_s=wall_s,
        cpu_s=stats.cpu_s,
        scene_builds=stats.scene_builds,
        scene_build_s=stats.scene_build_s,
        worker_start_s=stats.worker_start_s,
        tail_idle_s=stats.tail_idle_s,
    )


def read_records(out_dir: Path) -> list[dict[str, Any]]:
    """Valid records of OUT/episodes.jsonl; a torn line (crash while writing) is dropped."""
    path = out_dir / RECORDS
    if not path.exists():
        return []
    records, torn = [], False
    for line in path.read_text().splitlines():
        if not line.strip():
            continue
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError:
            torn = True
    if torn:
        log.warning("%s: dropping an unreadable line (interrupted write)", path)
        path.write_text("".join(json.dumps(r) + "\n" for r in records))
    return records


def run_evaluation(
    episode_dir: str | Path,
    agent: str,
    args: argparse.Namespace,
    out_dir: str | Path,
    limit: int | None = None,
    workers: int = 1,
    progress: bool = True,
    fail_fast: bool = False,
    ray: RayOptions | None = None,
    episode_ids: Sequence[str] | None = None,
    policy: SchedulePolicy = DEFAULT_POLICY,
) -> dict[str, Any]:
    """Evaluate ``agent`` on the first ``limit`` episodes of the set; returns the summary.

    ``episode_ids``: only these episodes of the set (in the set's order; an id the set does not
    hold is an error), e.g. to re-run the episodes a change can affect.

    ``ray``: run the scenes as Ray tasks (``sim.evaluation.ray_backend``) instead of local
    worker processes; records and summary are the same.

    A multi-goal set (``imgnav episodes --goals N``) gets one record per sequence and its own
    summary (``sim.evaluation.multigoal``); ``args.subtask_budget`` (``--subtask-budget``) is
    its budget per goal, and ``args.memory`` (``--memory``) gives the goals of a sequence one
    memory of the home (resuming refuses to mix runs with and without it).

    ``policy``: how episodes are handed to workers (``sim.evaluation.schedule``); the default
    is the one to use, ``schedule.OLD_POLICY`` is the old way, for benchmarks."""
    from tqdm import tqdm

    es = load_any_set(episode_dir)
    multi = isinstance(es, SequenceSet)
    spec = get_spec(agent)
    args = _clean_args(args)
    budget: int | None = None
    if multi:
        from sim.evaluation import multigoal

        budget = multigoal.subtask_budget(args)
        if ray is not None:
            raise ValueError("--ray does not run multi-goal sets yet; use --workers")
        if multigoal.uses_memory(args) and spec.make_memory is None:
            raise ValueError(f"--memory: the agent {agent!r} keeps no memory of a home")
    elif getattr(args, "subtask_budget", None) is not None:
        raise ValueError("--subtask-budget is for multi-goal sets (imgnav episodes --goals N)")
    elif getattr(args, "memory", False):
        raise ValueError("--memory is for multi-goal sets (imgnav episodes --goals N)")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    selected: list[Episode | SequenceEpisode] = list(es.episodes)
    if episode_ids is not None:
        wanted = set(episode_ids)
        missing = sorted(wanted - {e.episode_id for e in selected})
        if missing:
            raise ValueError(
                f"{episode_dir} has no episode(s) {', '.join(missing[:5])}{' ...' if len(missing) > 5 else ''}"
            )
        selected = [e for e in selected if e.episode_id in wanted]
    selected = selected[:limit] if limit else selected
    done = {r["episode_id"]: r for r in read_records(out)}
    others = {r.get("agent") for r in done.values()} - {agent}
    if others:
        raise ValueError(
            f"{out / RECORDS} holds records of agent(s) {sorted(map(str, others))}; use another --out or --overwrite"
        )
    realism = realism_of(args)
    wanted_realism = realism.describe() if realism is not None else None
    mixed = {json.dumps(r.get("realism")) for r in done.values()} - {json.dumps(wanted_realism)}
    if mixed:
        raise ValueError(
            f"{out / RECORDS} holds records made with another realism profile ({', '.join(sorted(mixed))}); "
            "use another --out or --overwrite"
        )
    if multi and {r.get("subtask_budget") for r in done.values()} - {budget}:
        raise ValueError(
            f"{out / RECORDS} holds sequences run with another --subtask-budget than {budget}; "
            "use another --out or --overwrite"
        )
    memory = multi and multigoal.uses_memory(args)
    if multi and {bool(r.get("memory", False)) for r in done.values()} - {memory}:
        raise ValueError(
            f"{out / RECORDS} holds sequences run {'without' if memory else 'with'} --memory; "
            "use another --out or --overwrite"
        )
    todo = [e for e in selected if e.episode_id not in done]
    schedule = Schedule(units_of(todo), policy)
    if done:
        log.info("resuming: %d of %d episodes already done", len(selected) - len(todo), len(selected))
    bar = tqdm(
        total=len(selected), initial=len(selected) - len(todo), desc=f"eval {agent}", unit="ep", disable=not progress
    )
    ran: list[dict[str, Any]] = []  # the records of this invocation
    stats = RunStats()
    t0, cpu0 = time.perf_counter(), cpu_seconds()
    with (out / RECORDS).open("a") as fh:

        def write(rec: dict[str, Any]) -> None:
            fh.write(json.dumps(_json_safe(rec)) + "\n")
            fh.flush()
            done[rec["episode_id"]] = rec
            ran.append(rec)
            bar.update(1)
            bar.set_postfix(sr=f"{sum(bool(done[i]['success']) for i in done) / len(done):.2f}")

        n = min(workers, schedule.max_parallel)
        if ray is not None:
            from sim.evaluation.ray_backend import run_scenes_on_ray

            assert isinstance(es, EpisodeSet)  # multi-goal sets were refused above
            # one Ray task per home, homes longest first (in the order one worker would run them)
            seed_of = {e.episode_id: e.scene_seed for e in todo}
            groups: dict[int, list[str]] = {}
            for unit_id in schedule.plan():
                groups.setdefault(seed_of[unit_id], []).append(unit_id)
            cpus = run_scenes_on_ray(
                ray, es, list(groups.values()), agent, args, fail_fast, write, is_done=done.__contains__
            )
            stats.workers = max(1, cpus)
            # a task's episodes share its build; the CPU of Ray's workers is not ours to read
            stats.built_from_records(ran)
        elif n <= 1:
            run_here(es, schedule, spec, args, fail_fast, write, stats)
            stats.cpu_s = cpu_seconds() - cpu0
        else:
            run_workers(str(episode_dir), schedule, n, agent, args, fail_fast, write, stats)
            stats.cpu_s = cpu_seconds() - cpu0
    wall_s = time.perf_counter() - t0
    bar.close()
    records = [done[e.episode_id] for e in selected if e.episode_id in done]
    if multi:
        summary = multigoal.summarize_sequences(records, spec)
    else:
        summary = aggregate([{**r, "ne": float(r["ne"])} for r in records])
    summary.update(
        {
            "agent": agent,
            "realism": wanted_realism or {"profile": "clean"},
            "episode_set": str(episode_dir),
            "split": es.split,
            "errors": sum(1 for r in records if r.get("error")),
            "timing": {
                "wall_s_this_run": r4(wall_s),
                "agent_ms_per_step": r4(sum(r["timing"]["agent_ms_per_step"] for r in records) / max(len(records), 1)),
                "sim_ms_per_step": r4(sum(r["timing"]["sim_ms_per_step"] for r in records) / max(len(records), 1)),
                **_cpu_per_record(records, "sequence" if multi else "episode"),
            },
            "throughput": _throughput_block(out, ran, wall_s, stats),
        }
    )
    if spec.summarize and not multi:  # a multi-goal summary has the agent's own over its subtasks
        summary.update(dict(spec.summarize(records)))
    (out / SUMMARY).write_text(json.dumps(_json_safe(summary), indent=1) + "\n")
    return summary
