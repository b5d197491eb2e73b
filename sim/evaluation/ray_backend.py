"""Evaluation across machines on Ray (``imgnav eval --ray ADDRESS``, docs/architecture.md section 9).

The work unit is one home's episodes (``runner.run_scene`` builds the home once), homes
longest first in the runner's order (local workers instead take one episode at a time and
may share a large home: ``sim.evaluation.schedule``). Each unit is a Ray task with
``num_cpus=1`` and one torch thread, written as a Ray generator so every episode record
streams back to the driver as soon as it finishes; the driver appends it to
``OUT/episodes.jsonl`` through the same ``write`` as the local runner, so records, progress
bar, resume and summary are the same.

* No shared filesystem: a task carries its episodes' JSON and the goal PNGs' bytes (the
  driver reads them; workers never open the episode directory), and returns the small
  JSON records (no images go back through the object store).
* Backpressure: at most ``max_in_flight`` tasks are submitted at a time (default twice the
  cluster's CPUs), so payloads do not pile up in the object store.
* Faults: a task whose worker process or node dies (any Ray system error, i.e. not a
  Python exception from our code) is submitted again with the scene's episodes that
  have not been recorded yet, at most ``max_retries`` times; after that those episodes
  are recorded with the error (``runner.error_record``), as local runs record errors. An
  episode id is written at most once. A Python exception escaping a task (the home
  cannot be built, or ``--fail-fast``) stops the run as it does with local workers.
  Ctrl-C (or any exception in the driver) cancels the tasks in flight and disconnects;
  what was written stays, and a re-run resumes.
* Code and calibration reach the workers by the same install on every node (or a
  ``runtime_env`` passed through ``RayOptions``); see README "Evaluating on a cluster".

``ray`` is imported only here and only when a Ray run starts.
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

from sim.episodes import Episode, EpisodeSet

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class RayOptions:
    """How to run on Ray.

    address: ``local`` (start Ray on this machine with ``num_cpus`` CPUs), ``auto`` (join the
        cluster this machine is a node of), or a cluster address (``HOST:PORT`` of the head's
        GCS, or ``ray://HOST:10001`` for Ray Client from outside the cluster).
    num_cpus: CPUs of the ``local`` instance (``--workers``); ignored otherwise.
    max_retries: re-submissions of a scene whose task was lost (worker or node died).
    max_in_flight: tasks submitted at once; None = twice the cluster's CPUs.
    runtime_env: passed to ``ray.init`` (e.g. ``{"working_dir": ".", "pip": [...]}``) when
        the nodes do not share the install.
    crash_before: fault injection for tests: ``(episode_id, attempts)`` pairs; a task's
        worker process SIGKILLs itself just before running that episode on the first
        ``attempts`` attempts of its scene.
    on_record: driver-side hook called after each record is written (tests).
    """

    address: str = "local"
    num_cpus: int = 2
    max_retries: int = 2
    max_in_flight: int | None = None
    runtime_env: dict[str, Any] | None = None
    crash_before: tuple[tuple[str, int], ...] = ()
    on_record: Callable[[dict[str, Any]], None] | None = field(default=None, compare=False)


def import_ray():
    try:
        import ray
    except ImportError as exc:  # pragma: no cover - ray is a declared dependency
        raise RuntimeError("--ray needs the `ray` package (pip install ray==2.60.0)") from exc
    return ray


def connect(options: RayOptions) -> bool:
    """Connect this process to Ray as the options say; True if it must disconnect later
    (an already connected process, e.g. a test's, is reused and left connected)."""
    ray = import_ray()
    if ray.is_initialized():
        return False
    kw: dict[str, Any] = {"logging_level": logging.WARNING, "include_dashboard": False}
    if options.runtime_env:
        kw["runtime_env"] = options.runtime_env
    t0 = time.perf_counter()
    try:
        if options.address == "local":
            # address="local" always starts a new instance; without it ray.init joins whatever
            # /tmp/ray/ray_current_cluster names, even a cluster that no longer runs. Ray runs its
            # workers at nice 15 (to favour its own daemons); on a shared machine that starves them
            # against `--workers` processes at nice 0, so here they get the driver's priority.
            ray.init(address="local", num_cpus=max(1, options.num_cpus), _system_config={"worker_niceness": 0}, **kw)
        else:
            kw.pop("include_dashboard")  # only for a cluster started here
            ray.init(address=options.address, **kw)
    except ConnectionError as exc:
        raise ValueError(f"--ray {options.address}: cannot connect to a Ray cluster ({exc})") from exc
    log.info(
        "ray %s: %s CPUs, connected in %.1f s",
        options.address,
        int(ray.cluster_resources().get("CPU", 0)),
        time.perf_counter() - t0,
    )
    return True


# --- worker side ------------------------------------------------------------------------

_PREPARED: set[str] = set()  # agents whose worker_init ran in this worker process


def _one_thread(args: argparse.Namespace) -> argparse.Namespace:
    """A task has one CPU: one torch thread. Ray sets OMP_NUM_THREADS, but torch's pool may
    already exist and agents size it from their own options, so set both explicitly."""
    if getattr(args, "modiin_threads", 0) is None:  # Mod-IIN's default would be 2 // --workers
        args = argparse.Namespace(**{**vars(args), "modiin_threads": 1})
    return args


def _set_torch_threads() -> None:
    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(1)


def scene_task(payload: dict[str, Any]) -> Iterator[dict[str, Any]]:
    """Ray generator task: one home's episodes; yields ``{"record", "node", "pid"}`` per episode."""
    import cv2
    import numpy as np

    from sim.evaluation.registry import get_spec
    from sim.evaluation.runner import run_scene

    agent, args = payload["agent"], payload["args"]
    _set_torch_threads()
    if agent not in _PREPARED:
        spec = get_spec(agent)
        if spec.worker_init:
            spec.worker_init(args)
        _PREPARED.add(agent)
    _set_torch_threads()
    episodes = [Episode.from_json(e) for e in payload["episodes"]]
    goals = []
    for e, png in zip(episodes, payload["goal_png"], strict=True):
        bgr = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
        if bgr is None:
            raise ValueError(f"episode {e.episode_id}: goal image bytes are not an image")
        goals.append(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))
    crash = set(payload.get("crash_before", ()))
    node = _node_ip()
    # run_scene builds the home once and runs episode k when asked for record k, so the
    # record streams back before the next episode starts
    records = run_scene(episodes, goals, agent, args, payload["fail_fast"])
    for e in episodes:
        if e.episode_id in crash:
            log.warning("fault injection: killing worker %d before %s", os.getpid(), e.episode_id)
            os.kill(os.getpid(), signal.SIGKILL)
        yield {"record": next(records), "node": node, "pid": os.getpid()}


def _node_ip() -> str:
    import ray

    return ray.util.get_node_ip_address()


# --- driver side ------------------------------------------------------------------------


@dataclass(slots=True)
class _Scene:
    """One home's episodes still to be recorded, and how often its task was lost."""

    episodes: list[Episode]
    lost: int = 0


def _payload(
    scene: _Scene, es: EpisodeSet, agent: str, args: argparse.Namespace, fail_fast: bool, options: RayOptions
) -> dict[str, Any]:
    attempts = dict(options.crash_before)
    crash = [e.episode_id for e in scene.episodes if scene.lost < attempts.get(e.episode_id, 0)]
    return {
        "agent": agent,
        "args": args,
        "fail_fast": fail_fast,
        "crash_before": crash,
        "episodes": [e.to_json() for e in scene.episodes],
        "goal_png": [es.goal_image_path(e).read_bytes() for e in scene.episodes],
    }


def run_scenes_on_ray(
    options: RayOptions,
    es: EpisodeSet,
    groups: Sequence[Sequence[str]],
    agent: str,
    args: argparse.Namespace,
    fail_fast: bool,
    write: Callable[[dict[str, Any]], None],
    is_done: Callable[[str], bool],
) -> int:
    """Run the scene groups (lists of episode ids, one home each) as Ray tasks in the order
    given (the runner's: homes longest first), calling ``write(record)`` on the driver for each
    finished episode (at most once per id). Returns the most CPUs the cluster had (0: no task)."""
    ray = import_ray()
    args = _one_thread(args)
    todo = deque(_Scene([es.by_id(i) for i in ids]) for ids in groups)
    if not todo:
        return 0
    disconnect = connect(options)
    most_cpus = 0
    task = ray.remote(num_cpus=1, max_retries=0)(scene_task)  # retries are ours: only unrecorded episodes
    in_flight: dict[Any, _Scene] = {}
    n_tasks = n_lost = n_failed = 0
    try:
        while todo or in_flight:
            cpus = max(1, int(ray.cluster_resources().get("CPU", 1)))
            most_cpus = max(most_cpus, cpus)
            limit = options.max_in_flight or 2 * cpus
            while todo and len(in_flight) < limit:
                scene = todo.popleft()
                in_flight[task.remote(_payload(scene, es, agent, args, fail_fast, options))] = scene
                n_tasks += 1
            ready, _ = ray.wait(list(in_flight), num_returns=1)
            for gen in ready:
                scene = in_flight[gen]
                try:
                    item = ray.get(next(gen))
                except StopIteration:
                    del in_flight[gen]
                    if scene.episodes:  # cannot happen with run_scene; never drop episodes silently
                        raise RuntimeError(
                            f"a Ray task ended without {[e.episode_id for e in scene.episodes]}"
                        ) from None
                    continue
                except ray.exceptions.RayTaskError as exc:  # our code raised: stop, as local workers do
                    raise RuntimeError(f"an evaluation task failed: {exc}") from exc
                except ray.exceptions.RayError as exc:  # the worker or node was lost
                    del in_flight[gen]
                    scene.lost += 1
                    n_lost += 1
                    ids = [e.episode_id for e in scene.episodes]
                    if not ids:  # lost after its last record: nothing left to run
                        continue
                    if scene.lost <= options.max_retries:
                        log.warning(
                            "ray: task of scene %d lost (%s: %s); retry %d/%d with %d episode(s)",
                            scene.episodes[0].scene_seed,
                            type(exc).__name__,
                            _first_line(exc),
                            scene.lost,
                            options.max_retries,
                            len(ids),
                        )
                        todo.appendleft(scene)
                    else:
                        log.error(
                            "ray: task of scene %d lost %d times; recording %s as errors",
                            scene.episodes[0].scene_seed,
                            scene.lost,
                            ids,
                        )
                        from sim.evaluation.runner import error_record

                        for e in scene.episodes:
                            if not is_done(e.episode_id):
                                _emit(
                                    error_record(
                                        e,
                                        agent,
                                        f"{type(exc).__name__}: task lost {scene.lost} times ({_first_line(exc)})",
                                    ),
                                    write,
                                    options,
                                )
                                n_failed += 1
                    continue
                rec = item["record"]
                scene.episodes = [e for e in scene.episodes if e.episode_id != rec["episode_id"]]
                if is_done(rec["episode_id"]):
                    log.warning("ray: %s arrived twice; kept the first record", rec["episode_id"])
                    continue
                _emit(rec, write, options)
    except BaseException:  # Ctrl-C or a failed task: stop the work in flight, keep what was written
        for gen in in_flight:
            ray.cancel(gen, force=True)
        raise
    finally:
        if disconnect:
            ray.shutdown()
    log.info(
        "ray: %d task(s), %d lost and retried or given up, %d episode(s) recorded as errors", n_tasks, n_lost, n_failed
    )
    return most_cpus


def _emit(rec: dict[str, Any], write: Callable[[dict[str, Any]], None], options: RayOptions) -> None:
    write(rec)
    if options.on_record is not None:
        options.on_record(rec)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else ""
