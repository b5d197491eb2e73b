"""The evaluation schedule (issue 32): homes longest first, a large home split across workers,
no worker idle while work is left; the throughput block of summary.json."""

from __future__ import annotations

import pytest

from agent.types import Pose2D
from sim.episodes import Episode
from sim.evaluation.schedule import (
    OLD_POLICY,
    STEPS_FIXED,
    STEPS_PER_M,
    Schedule,
    Unit,
    replay,
    simulate,
    throughput,
    unit_cost,
)
from sim.sequences import SequenceEpisode, SequenceGoal


def _episode(eid: str, seed: int, path_m: float) -> Episode:
    return Episode(eid, "val", seed, Pose2D(), 1, "tv", f"goals/{eid}.png", ((1.0, 1.0),), path_m)


def _simulate(schedule: Schedule, durations: dict[str, float], workers: int, build_s: float = 0.0):
    """``simulate`` with every home (scene seeds 0-99 in these tests) taking ``build_s`` to build."""
    return simulate(schedule, durations, dict.fromkeys(range(100), build_s), workers)


def test_cost_grows_with_the_shortest_path_and_a_sequence_sums_its_goals() -> None:
    assert unit_cost(_episode("a", 1, 2.0)) == pytest.approx(STEPS_FIXED + 2.0 * STEPS_PER_M)
    assert unit_cost(_episode("b", 1, 9.0)) > unit_cost(_episode("c", 1, 3.0))

    def goal(chain_m: float | None) -> SequenceGoal:
        info = {} if chain_m is None else {"oracle_chain_geodesic_m": chain_m}
        return SequenceGoal(1, "tv", "g.png", ((1.0, 1.0),), "new", None, info)

    seq = SequenceEpisode("q", "val", 1, Pose2D(), 2.0, (goal(None), goal(5.0), goal(1.0)))
    assert unit_cost(seq) == pytest.approx(3 * STEPS_FIXED + (2.0 + 5.0 + 1.0) * STEPS_PER_M)


def test_homes_and_their_episodes_are_run_longest_first() -> None:
    units = [
        Unit("a0", 1, 10.0),
        Unit("b0", 2, 30.0),
        Unit("a1", 1, 15.0),
        Unit("c0", 3, 50.0),
        Unit("b1", 2, 5.0),
    ]
    # home 3 (50) before home 2 (35) before home 1 (25); in a home, the longer episode first
    assert Schedule(units).plan() == ["c0", "b0", "b1", "a1", "a0"]
    # the old order: most episodes first, the set's order otherwise
    assert Schedule(units, OLD_POLICY).plan() == ["a0", "a1", "b0", "b1", "c0"]


def test_a_large_home_is_split_across_workers() -> None:
    units = [Unit(f"h{k}", 7, 10.0) for k in range(4)] + [Unit("s0", 8, 5.0)]
    durations = {u.unit_id: u.cost for u in units}
    s = Schedule(units)
    assert s.max_parallel == 5
    clock, ran = _simulate(s, durations, workers=2, build_s=1.0)
    homes = [{seed for seed, _ in r} for r in ran]
    assert all(7 in h for h in homes)  # both workers ran episodes of the big home
    assert s.builds == 3  # the big home twice, the small one once
    assert max(clock) == pytest.approx(27.0)  # the best there is with 10 s units: 25 s + 2 builds on one worker
    # the old way: the big home as one block on one worker while the other finishes early
    old = Schedule(units, OLD_POLICY)
    assert old.max_parallel == 2
    old_clock, old_ran = _simulate(old, durations, workers=2, build_s=1.0)
    assert max(old_clock) == pytest.approx(41.0) and old.builds == 2
    assert {len(r) for r in old_ran} == {1, 4}
    # replay gives the same figures from recorded seconds
    homes_build = {7: 1.0, 8: 1.0}
    new = replay(units, durations, homes_build, workers=2)
    assert new["makespan_s"] == 27.0 and new["scene_builds"] == 3 and new["tail_idle_s"] == pytest.approx(6.0)
    assert new["busy_share"] == pytest.approx(45.0 / 54.0, abs=1e-4)
    was = replay(units, durations, homes_build, workers=2, policy=OLD_POLICY)
    assert was["makespan_s"] == 41.0 and was["tail_idle_s"] == pytest.approx(35.0)
    # one home: the old way ran it on one worker, the other core idle throughout
    one_home = [u for u in units if u.scene_seed == 7]
    assert replay(one_home, durations, homes_build, 2, OLD_POLICY)["tail_idle_s"] == pytest.approx(41.0)
    assert replay(one_home, durations, homes_build, 2)["makespan_s"] == 21.0


def test_a_worker_stays_in_its_home_and_joins_another_only_when_no_home_is_free() -> None:
    units = [Unit("a0", 1, 9.0), Unit("a1", 1, 8.0), Unit("a2", 1, 7.0), Unit("b0", 2, 6.0), Unit("c0", 3, 1.0)]
    s = Schedule(units)
    assert s.next_for(0) == units[0]  # worker 0 takes home 1, the longest
    assert s.next_for(1) == units[3]  # worker 1 the longest free home, not a second build of home 1
    assert s.next_for(1) == units[4]  # then the next free home
    assert s.next_for(0) == units[1]  # worker 0 stays in home 1
    assert s.next_for(1) == units[2]  # no home is free: worker 1 joins home 1
    assert s.next_for(0) is None and s.next_for(1) is None
    assert s.builds == 4


def test_no_worker_waits_while_work_is_left() -> None:
    """Random homes and costs, with the estimate off by up to 3x: every worker finishes within
    one unit (and a build) of the others, i.e. no tail where a worker idles while work is queued."""
    import random

    rng = random.Random(3)
    for _ in range(50):
        units = [Unit(f"u{k}", rng.randrange(6), rng.uniform(1.0, 20.0)) for k in range(rng.randrange(2, 25))]
        durations = {u.unit_id: u.cost * rng.uniform(0.3, 3.0) for u in units}
        for workers in (2, 3):
            s = Schedule(units)
            clock, ran = _simulate(s, durations, workers, build_s=1.0)
            assert sorted(u for r in ran for _, u in r) == sorted(durations)  # each unit once
            assert max(clock) - min(clock) <= max(durations.values()) + 1.0 + 1e-9


def _record(wall_s: float, cpu_s: float, subtasks: int = 0) -> dict:
    rec: dict = {"timing": {"wall_s": wall_s, "cpu_s": cpu_s}}
    if subtasks:
        rec["subtasks"] = [{"timing": {"wall_s": wall_s / subtasks}} for _ in range(subtasks)]
    return rec


def test_throughput_figures() -> None:
    recs = [_record(10.0, 8.0), _record(20.0, 18.0), _record(30.0, 29.0)]
    t = throughput(recs, workers=2, wall_s=40.0, cpu_s=72.0, scene_builds=3, scene_build_s=4.5, tail_idle_s=2.0)
    assert t["covers"] == "this_invocation" and t["episodes"] == 3 and t["workers"] == 2
    assert t["episodes_per_cpu_hour"] == pytest.approx(3 * 3600 / 72.0)
    assert t["episodes_per_wall_hour"] == pytest.approx(3 * 3600 / 40.0)
    assert t["episodes_per_core_hour"] == pytest.approx(3 * 3600 / 80.0)
    assert t["busy_share"] == pytest.approx(60.0 / 80.0)
    assert t["episode_cpu_s"] == pytest.approx(55.0) and t["cpu_s_source"] == "processes"
    assert t["scene_builds"] == 3 and t["tail_idle_s"] == 2.0
    assert throughput(list(reversed(recs)), workers=2, wall_s=40.0, cpu_s=72.0, scene_builds=3, scene_build_s=4.5) == {
        k: v for k, v in t.items() if k != "tail_idle_s"
    }  # the order of the records does not matter
    # no process CPU (Ray): the episodes' own; nothing run: no rates
    assert throughput(recs, workers=2, wall_s=40.0, cpu_s=None, scene_builds=0, scene_build_s=0.0)["cpu_s"] == 55.0
    empty = throughput([], workers=1, wall_s=0.1, cpu_s=0.1, scene_builds=0, scene_build_s=0.0)
    assert empty["episodes"] == 0 and empty["episodes_per_cpu_hour"] is None and empty["busy_share"] is None
    # multi-goal: per sequence and per subtask
    m = throughput([_record(30.0, 20.0, 3)], workers=1, wall_s=36.0, cpu_s=36.0, scene_builds=1, scene_build_s=1.0)
    assert m["sequences"] == 1 and m["subtasks"] == 3
    assert m["sequences_per_cpu_hour"] == pytest.approx(100.0) and m["subtasks_per_cpu_hour"] == pytest.approx(300.0)
    assert "episodes" not in m
