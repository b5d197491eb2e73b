"""How the units of an evaluation run are run: in this process, or on spawned worker processes.

``sim.evaluation.runner.run_evaluation`` decides what to run and writes records and the summary;
this module runs the units it is handed, one at a time per worker, as ``schedule.Schedule`` hands
them out:

* ``run_unit``: one episode (one sequence of a multi-goal set) in the home the worker last built
  (``HomeCache``), returning its record and the build seconds if the home was built for it;
* ``run_here``: the whole schedule in this process (one worker);
* ``run_workers``: the schedule on ``n`` spawned processes (``worker_main``), each with its share of
  the cores' thread pools (``worker_thread_env``), each ending itself when the evaluation that
  spawned it is gone (``exit_with_parent``);
* ``RunStats`` and ``cpu_seconds``: what the invocation measured besides the records (home builds,
  worker start-up, the idle tail, the CPU of this process and its workers) for summary.json's
  ``throughput`` block.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import multiprocessing as mp
import os
import resource
import threading
import time
import traceback
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

from sim.episodes import EpisodeSet, r4
from sim.evaluation.registry import AgentSpec, get_spec
from sim.evaluation.schedule import Schedule
from sim.sequences import SequenceSet, load_any_set
from sim.world import SimWorld

log = logging.getLogger(__name__)


_THREAD_ENV = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


@contextlib.contextmanager
def worker_thread_env(threads: int) -> Iterator[None]:
    """Spawned workers inherit this environment: each one's OpenMP/BLAS pools get its share of
    the cores (read when numpy and torch load), so n workers never start n x cores threads.
    torch's intra-op threads are set by the agent's ``worker_init``; OpenCV's below."""
    saved = {k: os.environ.get(k) for k in _THREAD_ENV}
    os.environ.update({k: str(threads) for k in _THREAD_ENV})
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


class HomeCache:
    """The home a worker has built (one at a time): the next episode of the same home reuses it."""

    def __init__(self) -> None:
        self.scene_seed: int | None = None
        self.world: SimWorld | None = None
        self.build_s = self.build_cpu_s = 0.0

    def world_for(self, scene_seed: int) -> tuple[SimWorld, float | None]:
        """The built home, and the seconds its build took if it was built now (None: reused)."""
        if self.world is not None and self.scene_seed == scene_seed:
            return self.world, None
        self.close()
        t0, c0 = time.perf_counter(), time.process_time()
        self.world = SimWorld.from_seed(scene_seed)
        self.scene_seed = scene_seed
        self.build_s, self.build_cpu_s = time.perf_counter() - t0, time.process_time() - c0
        return self.world, self.build_s

    def close(self) -> None:
        if self.world is not None:
            self.world.close()
        self.world, self.scene_seed = None, None


def run_unit(
    es: EpisodeSet | SequenceSet,
    cache: HomeCache,
    unit_id: str,
    spec: AgentSpec,
    args: argparse.Namespace,
    fail_fast: bool,
) -> tuple[dict[str, Any], float | None]:
    """Run one episode (one sequence of a multi-goal set) in the cached home; returns its record
    (``timing.scene_build_s``, ``scene_build_cpu_s``: the wall and CPU seconds of the build of
    the home it ran in, as ``run_scene`` records them) and the build seconds if the home was
    built for it."""
    from sim.evaluation.runner import run_episode  # the runner imports this module

    if isinstance(es, SequenceSet):  # one record per sequence (sim.evaluation.multigoal)
        from sim.evaluation.multigoal import run_sequence

        seq = es.by_id(unit_id)
        world, built = cache.world_for(seq.scene_seed)
        paths = [es.goal_image_path(seq, g) for g in range(len(seq.goals))]
        rec = run_sequence(world, seq, paths, spec, args, fail_fast)
    else:
        episode = es.by_id(unit_id)
        world, built = cache.world_for(episode.scene_seed)
        rec = run_episode(world, es, episode, spec, args, fail_fast)
    rec["timing"]["scene_build_s"] = r4(cache.build_s)
    rec["timing"]["scene_build_cpu_s"] = r4(cache.build_cpu_s)
    return rec, built


def exit_with_parent(parent_pid: int, period_s: float = 1.0) -> None:
    """End this worker when the evaluation that spawned it is gone (killed by a signal it could
    not clean up after, or by SIGKILL): an orphaned worker would go on running its episode, a
    sequence for minutes, on cores nobody uses its result from (the unit is run again on resume)."""

    def watch() -> None:
        while True:
            time.sleep(period_s)
            if os.getppid() != parent_pid:
                log.warning("the evaluation that started this worker is gone: stopping")
                os._exit(3)

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()


def worker_main(
    worker: int,
    episode_dir: str,
    agent: str,
    args: argparse.Namespace,
    fail_fast: bool,
    tasks,
    results,
    parent_pid: int,
) -> None:
    """One worker process: runs the unit ids its ``tasks`` queue hands it (None: stop), keeping
    the last home built; puts ``(kind, worker, payload)`` on ``results``: ``ready`` once set up,
    ``record`` with ``(record, build seconds or None)`` per unit, ``fatal`` with the traceback of
    an exception that stops the run, ``done`` at the end."""
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    exit_with_parent(parent_pid)
    cache = HomeCache()
    try:
        spec = get_spec(agent)
        if spec.worker_init:
            spec.worker_init(args)
        es = load_any_set(episode_dir)
        results.put(("ready", worker, None))
        while (unit_id := tasks.get()) is not None:
            results.put(("record", worker, run_unit(es, cache, unit_id, spec, args, fail_fast)))
    except Exception as exc:  # reported to the parent, which stops the run
        results.put(("fatal", worker, f"{type(exc).__name__}: {exc}\n{traceback.format_exc()}"))
    finally:
        cache.close()
    results.put(("done", worker, None))


@dataclass(slots=True)
class RunStats:
    """What one invocation measured besides the records (``schedule.throughput``)."""

    workers: int = 1
    cpu_s: float | None = None
    scene_builds: int = 0
    scene_build_s: float = 0.0
    worker_start_s: float | None = None
    tail_idle_s: float | None = None

    def built(self, seconds: float | None) -> None:
        if seconds is not None:
            self.scene_builds += 1
            self.scene_build_s += seconds

    def built_from_records(self, records: Sequence[dict[str, Any]]) -> None:
        """Builds read from records whose builder did not report them (Ray tasks): the episodes
        of one build share its home and ``timing.scene_build_s``."""
        for _, seconds in {(r["scene_seed"], r["timing"].get("scene_build_s")) for r in records}:
            self.built(float(seconds or 0.0))


def cpu_seconds() -> float:
    """CPU seconds used so far by this process and its waited-for children (the workers)."""
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def run_here(
    es: EpisodeSet | SequenceSet,
    schedule: Schedule,
    spec: AgentSpec,
    args: argparse.Namespace,
    fail_fast: bool,
    write: Callable[[dict[str, Any]], None],
    stats: RunStats,
) -> None:
    """Run the schedule in this process (one worker)."""
    t0 = time.perf_counter()
    if spec.worker_init:
        spec.worker_init(args)
    stats.worker_start_s = time.perf_counter() - t0
    cache = HomeCache()
    try:
        while (unit := schedule.next_for(0)) is not None:
            rec, built = run_unit(es, cache, unit.unit_id, spec, args, fail_fast)
            stats.built(built)
            write(rec)
    finally:
        cache.close()
    stats.tail_idle_s = 0.0


def run_workers(
    episode_dir: str,
    schedule: Schedule,
    n: int,
    agent: str,
    args: argparse.Namespace,
    fail_fast: bool,
    write: Callable[[dict[str, Any]], None],
    stats: RunStats,
) -> None:
    """Run the schedule on ``n`` spawned worker processes, handing each its next unit as it
    finishes the last (``schedule.Schedule``), so no worker waits while work is left."""
    ctx = mp.get_context("spawn")
    results = ctx.Queue()
    tasks = [ctx.Queue() for _ in range(n)]
    procs = [
        ctx.Process(target=worker_main, args=(w, episode_dir, agent, args, fail_fast, tasks[w], results, os.getpid()))
        for w in range(n)
    ]
    ran_out: dict[int, float] = {}  # worker -> when it was told nothing is left

    def hand_out(w: int) -> None:
        unit = schedule.next_for(w)
        tasks[w].put(None if unit is None else unit.unit_id)
        if unit is None:
            ran_out[w] = time.perf_counter()

    t0 = time.perf_counter()
    with worker_thread_env(max(1, (os.cpu_count() or 1) // n)):
        for p in procs:
            p.start()
    for w in range(n):  # queued now, so each worker starts its first unit as soon as it is ready
        hand_out(w)
    start_s, finished, fatal, ok = 0.0, 0, None, False
    try:
        while finished < n:
            kind, w, payload = results.get()
            if kind == "ready":
                start_s += time.perf_counter() - t0
            elif kind == "record":
                rec, built = payload
                stats.built(built)
                write(rec)
                hand_out(w)
            elif kind == "fatal":
                fatal = payload
                break
            else:
                finished += 1
        ok = fatal is None
    finally:
        t_end = time.perf_counter()
        if not ok:
            for p in procs:
                p.terminate()
        for p in procs:
            p.join()
    if fatal is not None:
        raise RuntimeError(f"an evaluation worker failed: {fatal}")
    stats.workers = n
    stats.worker_start_s = start_s
    stats.tail_idle_s = sum(t_end - t for t in ran_out.values())
