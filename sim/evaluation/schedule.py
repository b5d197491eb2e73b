"""Which episode each evaluation worker runs next, and the run's throughput figures.

The unit of work is one episode (one sequence in a multi-goal set); a worker keeps the home it
last built and reuses it for the next episode of the same home. ``Schedule`` hands units out one
at a time, as workers become free, so both cores stay busy to the end:

* Homes are taken longest first: ordered by their estimated cost (the sum of their episodes'),
  and a home's episodes longest first. The estimate uses only the episode data (``unit_cost``),
  since on a fresh run nothing else is known.
* A free worker goes on with the home it holds while that home has episodes left; otherwise it
  takes the longest home no other worker holds; when every home left is held by another worker,
  it joins the one with the most work left (a second build of that home, about 0.5-2 s, against
  tens of seconds per default-agent episode). So one large home never runs alone at the end.

The plan depends only on the units, never on timings, and an episode's record does not depend on
which worker ran it nor after which episodes (each starts from a fresh agent and backend), so
records are the same with any number of workers; only the order of lines in ``episodes.jsonl``
changes.

``SchedulePolicy(order="count", split_homes=False)`` is the scheduling this replaced (whole homes,
most episodes first, in the set's order otherwise), kept so ``benchmarks/bench_eval_scaling.py``
measures before and after in one run.

``throughput`` turns a run's measurements into the ``throughput`` block of ``summary.json``;
``replay`` says what a policy gives on idle cores from the CPU seconds a run recorded (what the
old scheduling would have given, without the load of a shared machine in the figures).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

from sim.episodes import Episode, r4
from sim.sequences import SequenceEpisode

# Estimated cost of an episode in agent steps: a fixed part (the look-around, the frames spent
# before the goal is seen, the share of failures that run to the budget) plus a part growing with
# the shortest path. Least squares of steps on the shortest path over the default agent's 100 val
# episodes (docs/results/val100/full): 191 steps + 24 per metre (Spearman 0.40: failures are not
# predictable from the episode, which is why work is also handed out as workers become free).
STEPS_FIXED = 190.0
STEPS_PER_M = 24.0


def unit_cost(unit: Episode | SequenceEpisode) -> float:
    """Estimated steps of one episode, or of a sequence (the sum over its goals; a later goal's
    path is the one from where the oracle ended the goal before, as the generator stored it)."""
    if isinstance(unit, SequenceEpisode):
        paths = [unit.geodesic_distance_m] + [
            float(g.info.get("oracle_chain_geodesic_m", unit.geodesic_distance_m)) for g in unit.goals[1:]
        ]
    else:
        paths = [unit.geodesic_distance_m]
    return sum(STEPS_FIXED + STEPS_PER_M * max(0.0, p) for p in paths)


@dataclass(frozen=True, slots=True)
class Unit:
    """One episode (or sequence) to run: its id, home and estimated cost in steps."""

    unit_id: str
    scene_seed: int
    cost: float


def units_of(episodes: Iterable[Episode | SequenceEpisode]) -> list[Unit]:
    return [Unit(e.episode_id, e.scene_seed, unit_cost(e)) for e in episodes]


@dataclass(frozen=True, slots=True)
class SchedulePolicy:
    """order: ``cost`` (homes and their episodes longest first by ``unit_cost``) or ``count``
    (homes with most episodes first, the set's order otherwise: the old way).
    split_homes: whether a free worker may join a home another worker holds."""

    order: Literal["cost", "count"] = "cost"
    split_homes: bool = True


DEFAULT_POLICY = SchedulePolicy()
OLD_POLICY = SchedulePolicy(order="count", split_homes=False)


@dataclass(slots=True)
class _Home:
    scene_seed: int
    queue: deque[Unit]
    holders: set[int] = field(default_factory=set)

    @property
    def left(self) -> float:
        return sum(u.cost for u in self.queue)


class Schedule:
    """Hands out units to workers (module docstring). ``next_for(worker)`` is called each time a
    worker is free; None means nothing is left for it. ``builds`` counts the homes handed to a
    worker that did not hold them (each one a build)."""

    def __init__(self, units: Sequence[Unit], policy: SchedulePolicy = DEFAULT_POLICY) -> None:
        self.policy = policy
        homes: dict[int, list[Unit]] = {}
        for u in units:
            homes.setdefault(u.scene_seed, []).append(u)
        first = {seed: k for k, seed in enumerate(homes)}
        if policy.order == "cost":
            for us in homes.values():
                us.sort(key=lambda u: -u.cost)  # stable: ties keep the set's order
            order = sorted(homes, key=lambda s: (-sum(u.cost for u in homes[s]), first[s]))
        else:
            order = sorted(homes, key=lambda s: (-len(homes[s]), first[s]))
        self._homes = [_Home(s, deque(homes[s])) for s in order]
        self._held: dict[int, _Home] = {}
        self.builds = 0

    @property
    def max_parallel(self) -> int:
        """How many workers can have work at once."""
        if self.policy.split_homes:
            return sum(len(h.queue) for h in self._homes)
        return len(self._homes)

    def plan(self) -> list[str]:
        """The unit ids in the order one worker would run them (does not change the schedule)."""
        return [u.unit_id for h in self._homes for u in h.queue]

    def next_for(self, worker: int) -> Unit | None:
        home = self._held.get(worker)
        if home is not None and home.queue:
            return home.queue.popleft()
        if home is not None:
            home.holders.discard(worker)
            del self._held[worker]
        free = [h for h in self._homes if h.queue and not h.holders]
        if free:
            home = free[0]  # homes are kept longest first
        elif self.policy.split_homes:
            held = [h for h in self._homes if h.queue]
            if not held:
                return None
            home = max(held, key=lambda h: h.left)  # max keeps the first of equals
        else:
            return None
        home.holders.add(worker)
        self._held[worker] = home
        self.builds += 1
        return home.queue.popleft()


def simulate(
    schedule: Schedule, unit_s: Mapping[str, float], build_s: Mapping[int, float], workers: int
) -> tuple[list[float], list[list[tuple[int, str]]]]:
    """Run ``schedule`` on ``workers`` simulated workers: unit ``u`` takes ``unit_s[u]``, a home
    the worker does not hold ``build_s[h]`` more (0 when missing). Returns each worker's finishing
    time and the (home, unit) it ran, in order."""
    clock = [0.0] * workers
    held: list[int | None] = [None] * workers
    ran: list[list[tuple[int, str]]] = [[] for _ in range(workers)]
    active = set(range(workers))
    while active:
        w = min(active, key=lambda k: (clock[k], k))  # the next worker to be free
        unit = schedule.next_for(w)
        if unit is None:
            active.discard(w)
            continue
        if held[w] != unit.scene_seed:
            clock[w] += build_s.get(unit.scene_seed, 0.0)
            held[w] = unit.scene_seed
        clock[w] += unit_s[unit.unit_id]
        ran[w].append((unit.scene_seed, unit.unit_id))
    return clock, ran


def replay(
    units: Sequence[Unit],
    unit_s: Mapping[str, float],
    build_s: Mapping[int, float],
    workers: int,
    policy: SchedulePolicy = DEFAULT_POLICY,
) -> dict[str, float]:
    """What ``policy`` gives on ``workers`` idle cores when unit ``u`` takes ``unit_s[u]`` and
    every build of home ``h`` takes ``build_s[h]`` (e.g. the CPU seconds of a run's records: on a
    loaded machine they are close to what a core of one's own would take, wall times are not).
    Start-up is left out (the same for every policy). Returns the makespan, the busy share (the
    units' seconds over workers x makespan), units per core-hour, the builds and the idle tail
    (summed over workers, from running out of work, or never getting any, to the end)."""
    schedule = Schedule(units, policy)
    n = max(1, min(workers, schedule.max_parallel))
    clock, _ = simulate(schedule, unit_s, build_s, n)
    makespan = max(clock)
    busy = sum(unit_s[u.unit_id] for u in units)
    core_s = workers * makespan
    return {
        "makespan_s": r4(makespan),
        "busy_share": r4(busy / core_s) if core_s > 0 else float("nan"),
        "units_per_core_hour": r4(3600.0 * len(units) / core_s) if core_s > 0 else float("nan"),
        "scene_builds": schedule.builds,
        "tail_idle_s": r4(sum(makespan - c for c in clock) + (workers - n) * makespan),
    }


def throughput(
    records: Sequence[dict[str, Any]],
    *,
    workers: int,
    wall_s: float,
    cpu_s: float | None,
    scene_builds: int,
    scene_build_s: float,
    worker_start_s: float | None = None,
    tail_idle_s: float | None = None,
) -> dict[str, Any]:
    """The ``throughput`` block of summary.json for the units run by one invocation (``records``:
    theirs only; order does not matter).

    cpu_s: CPU time of the evaluation's processes (the runner and its workers: start-up, home
    builds and episodes); None where it cannot be measured (Ray tasks on other machines), then
    the episodes' own CPU time is used. Rates per hour are None when nothing ran.
    busy_share: the episodes' wall time over workers x run wall time (the rest is start-up, home
    builds and idle workers). A multi-goal run's records are sequences: the figures are given per
    sequence and per subtask."""
    multi = any("subtasks" in r for r in records)
    unit = "sequences" if multi else "episodes"
    n = len(records)
    episode_wall_s = sum(float(r["timing"]["wall_s"]) for r in records)
    episode_cpu_s = sum(float(r["timing"].get("cpu_s", 0.0)) for r in records)
    cpu_measured = cpu_s is not None
    cpu = float(cpu_s) if cpu_s is not None else episode_cpu_s
    core_s = workers * wall_s

    def per_hour(count: int, seconds: float) -> float | None:
        return r4(3600.0 * count / seconds) if count and seconds > 0 else None

    out: dict[str, Any] = {
        "covers": "this_invocation",
        unit: n,
        "workers": workers,
        "wall_s": r4(wall_s),
        "cpu_s": r4(cpu),
        "cpu_s_source": "processes" if cpu_measured else "episodes",
        "episode_wall_s": r4(episode_wall_s),
        "episode_cpu_s": r4(episode_cpu_s),
        "scene_builds": scene_builds,
        "scene_build_s": r4(scene_build_s),
        f"{unit}_per_cpu_hour": per_hour(n, cpu),
        f"{unit}_per_wall_hour": per_hour(n, wall_s),
        f"{unit}_per_core_hour": per_hour(n, core_s),
        "busy_share": r4(episode_wall_s / core_s) if n and core_s > 0 else None,
    }
    if worker_start_s is not None:
        out["worker_start_s"] = r4(worker_start_s)
    if tail_idle_s is not None:
        out["tail_idle_s"] = r4(tail_idle_s)
    if multi:
        subtasks = sum(len(r["subtasks"]) for r in records)
        out["subtasks"] = subtasks
        out["subtasks_per_cpu_hour"] = per_hour(subtasks, cpu)
        out["subtasks_per_wall_hour"] = per_hour(subtasks, wall_s)
        out["subtasks_per_core_hour"] = per_hour(subtasks, core_s)
    return out
