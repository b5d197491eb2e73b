"""SQLite run records: round trips, JSON safety, restart recovery."""

from __future__ import annotations

from pathlib import Path

from console.step_schema import StepRow
from console.store import RunStore


def _step(i: int, score: float | None = 1.5) -> StepRow:
    return StepRow(
        i,
        100.0 + i,
        1,
        0.25 * i,
        0.0,
        0.1,
        "explore",
        "nearest frontier",
        score,
        10.0,
        False,
        0,
        1.0,
        2.0,
        "frontier",
        None,
        {"total": 12.5},
    )


def test_run_round_trip(tmp_path: Path) -> None:
    store = RunStore(tmp_path / "db.sqlite3")
    store.create_run(
        "a" * 12, backend="sim", options={"home": "h0"}, goal={"sha256": "x"}, target={"instance": 3}, created_s=1.0
    )
    store.update_run("a" * 12, status="running", started_s=2.0, agent_config={"tau": 10.0})
    for i in range(3):
        store.add_step("a" * 12, _step(i))
    store.update_run("a" * 12, status="finished", outcome="success", metrics={"spl": 0.5, "ne_m": float("inf")})
    row = store.get_run("a" * 12)
    assert row is not None
    assert row["status"] == "finished" and row["n_steps"] == 3
    assert row["options"] == {"home": "h0"} and row["target"] == {"instance": 3}
    assert row["metrics"] == {"spl": 0.5, "ne_m": None}  # non-finite floats become null
    steps = store.steps("a" * 12)
    assert [s.step for s in steps] == [0, 1, 2] and steps[1].timings == {"total": 12.5}
    assert store.list_runs()[0]["id"] == "a" * 12


def test_active_runs_become_interrupted_after_restart(tmp_path: Path) -> None:
    db = tmp_path / "db.sqlite3"
    store = RunStore(db)
    store.create_run("b" * 12, backend="sim", options={}, goal={}, target=None, created_s=1.0)
    store.update_run("b" * 12, status="running")
    store.create_run("c" * 12, backend="sim", options={}, goal={}, target=None, created_s=2.0)
    store.update_run("c" * 12, status="finished", outcome="unscored")
    store.close()  # the process dies with a run active

    again = RunStore(db)
    assert again.mark_interrupted() == ["b" * 12]
    assert again.get_run("b" * 12)["status"] == "interrupted"
    assert again.get_run("c" * 12)["status"] == "finished"
    assert again.mark_interrupted() == []


def test_interrupted_run_ends_at_its_last_step_not_at_the_restart(tmp_path: Path) -> None:
    """A console killed mid-run (SIGKILL: nothing written at the end) leaves the run active;
    the next start marks it interrupted with the time of its last recorded step."""
    db = tmp_path / "db.sqlite3"
    store = RunStore(db)
    store.create_run("d" * 12, backend="sim", options={}, goal={}, target=None, created_s=50.0)
    store.update_run("d" * 12, status="running", started_s=60.0)
    for i in range(4):
        store.add_step("d" * 12, _step(i))  # t_s = 100 + i
    store.create_run("e" * 12, backend="sim", options={}, goal={}, target=None, created_s=70.0)
    store.update_run("e" * 12, status="running", started_s=71.0)  # killed before its first step
    store.close()

    again = RunStore(db)
    assert sorted(again.mark_interrupted()) == ["d" * 12, "e" * 12]
    assert again.get_run("d" * 12)["ended_s"] == 103.0
    assert again.get_run("e" * 12)["ended_s"] == 71.0
    assert len(again.steps("d" * 12)) == 4


def test_steps_keep_the_re_id_gate_and_older_files_gain_its_columns(tmp_path: Path) -> None:
    import sqlite3
    from dataclasses import replace

    db = tmp_path / "db.sqlite3"
    store = RunStore(db)
    store.create_run("b" * 12, backend="sim", options={}, goal={}, target=None, created_s=1.0)
    store.add_step("b" * 12, replace(_step(0, score=0.0), reid_full_matcher=False, reid_gate_score=12.0))
    store.add_step(
        "b" * 12, replace(_step(1, score=80.5), reid_full_matcher=True, reid_gate_score=140.0, reid_exit_score=41.5)
    )
    store.add_step("b" * 12, _step(2))  # gate off: neither is known
    store.add_step(
        "b" * 12, replace(_step(3, score=0.0), reid_full_matcher=False, reid_gate_score=30.0, reid_exit_score=0.75)
    )  # stopped by the exit stage
    got = store.steps("b" * 12)
    assert [(s.reid_full_matcher, s.reid_gate_score, s.reid_exit_score) for s in got] == [
        (False, 12.0, None),
        (True, 140.0, 41.5),
        (None, None, None),
        (False, 30.0, 0.75),
    ]
    # a data directory from before the gate: its steps table lacks the columns; opening adds them
    old = tmp_path / "old.sqlite3"
    con = sqlite3.connect(old)
    con.executescript(
        "CREATE TABLE steps (run_id TEXT NOT NULL, step INTEGER NOT NULL, t_s REAL NOT NULL, action INTEGER NOT NULL,"
        " x_m REAL NOT NULL, y_m REAL NOT NULL, yaw_rad REAL NOT NULL, mode TEXT NOT NULL, reason TEXT NOT NULL,"
        " reid_score REAL, reid_tau REAL, goal_detected INTEGER NOT NULL, n_goal_points INTEGER NOT NULL,"
        " target_x_m REAL, target_y_m REAL, target_kind TEXT, planner_error TEXT, timings_json TEXT NOT NULL,"
        " PRIMARY KEY (run_id, step));"
        "INSERT INTO steps VALUES ('cccccccccccc', 0, 1.0, 1, 0, 0, 0, 'explore', '', 3.0, 10.0, 0, 0, NULL, NULL,"
        " NULL, NULL, '{}');"
    )
    con.commit()
    con.close()
    reopened = RunStore(old)
    assert [(s.reid_score, s.reid_full_matcher, s.reid_exit_score) for s in reopened.steps("c" * 12)] == [
        (3.0, None, None)
    ]
