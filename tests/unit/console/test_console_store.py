"""SQLite run records: round trips, JSON safety, restart recovery."""

from __future__ import annotations

from pathlib import Path

from console.store import RunStore, StepRow


def _step(i: int, score: float | None = 1.5) -> StepRow:
    return StepRow(i, 100.0 + i, 1, 0.25 * i, 0.0, 0.1, "explore", "nearest frontier", score, 10.0, False, 0,
                   1.0, 2.0, "frontier", None, {"total": 12.5})


def test_run_round_trip(tmp_path: Path) -> None:
    store = RunStore(tmp_path / "db.sqlite3")
    store.create_run("a" * 12, backend="sim", options={"home": "h0"}, goal={"sha256": "x"}, target={"instance": 3}, created_s=1.0)
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
