"""The one step schema (console.step_schema): a field declared once in ``StepRow`` reaches the
SQLite table (created or migrated), the API's steps, the event stream, trajectory.json, the replay
timeline and the replay's rebuilt record; data directories of the previous schema still open."""

from __future__ import annotations

import dataclasses
import functools
import json
import sqlite3
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

import console.context
from agent.types import SIM_INTRINSICS, Action, AgentRecord, Pose2D
from console.api import create_app
from console.context import Console, ConsoleConfig
from console.session import StepRecord
from console.step_schema import (
    BOOL,
    INTEGER,
    NAMES,
    REAL,
    STEP_SCHEMA,
    TEXT,
    Column,
    SchemaError,
    StepRow,
    StepSchema,
    step_field,
)
from console.store import RunStore
from tests.helpers.console_testkit import ScriptedProvider, encode, poll, textured_rgb

# The console's database as written before the one step schema (console/store.py at e594bfe),
# copied here on purpose: files written by it must keep opening.
PREVIOUS_SCHEMA_SQL = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS runs (
    id              TEXT PRIMARY KEY,
    created_s       REAL NOT NULL,
    started_s       REAL,
    ended_s         REAL,
    status          TEXT NOT NULL,
    backend         TEXT NOT NULL,
    options_json    TEXT NOT NULL,
    agent_json      TEXT NOT NULL DEFAULT '{}',
    goal_json       TEXT NOT NULL,
    target_json     TEXT,
    outcome         TEXT,
    outcome_detail  TEXT,
    metrics_json    TEXT,
    timings_json    TEXT NOT NULL DEFAULT '{}',
    n_steps         INTEGER NOT NULL DEFAULT 0,
    error           TEXT
);
CREATE INDEX IF NOT EXISTS runs_created ON runs (created_s);
CREATE TABLE IF NOT EXISTS steps (
    run_id          TEXT NOT NULL REFERENCES runs (id) ON DELETE CASCADE,
    step            INTEGER NOT NULL,
    t_s             REAL NOT NULL,
    action          INTEGER NOT NULL,
    x_m             REAL NOT NULL,
    y_m             REAL NOT NULL,
    yaw_rad         REAL NOT NULL,
    mode            TEXT NOT NULL,
    reason          TEXT NOT NULL,
    reid_score      REAL,
    reid_tau        REAL,
    goal_detected   INTEGER NOT NULL,
    n_goal_points   INTEGER NOT NULL,
    target_x_m      REAL,
    target_y_m      REAL,
    target_kind     TEXT,
    planner_error   TEXT,
    timings_json    TEXT NOT NULL,
    reid_full_matcher INTEGER,
    reid_gate_score REAL,
    reid_exit_score REAL,
    PRIMARY KEY (run_id, step)
);
CREATE TABLE IF NOT EXISTS replay_steps (
    run_id          TEXT NOT NULL REFERENCES runs (id) ON DELETE CASCADE,
    step            INTEGER NOT NULL,
    frame_jpeg      BLOB NOT NULL,
    extras_json     TEXT NOT NULL,
    PRIMARY KEY (run_id, step)
);
CREATE TABLE IF NOT EXISTS replay_maps (
    run_id          TEXT NOT NULL REFERENCES runs (id) ON DELETE CASCADE,
    step            INTEGER NOT NULL,
    map_blob        BLOB NOT NULL,
    PRIMARY KEY (run_id, step)
);
"""

OLD_RUN = "0123456789ab"


def previous_database(path: Path) -> None:
    """A data directory's database from before, with one finished run of two steps."""
    con = sqlite3.connect(path)
    con.executescript(PREVIOUS_SCHEMA_SQL)
    con.execute(
        "INSERT INTO runs (id, created_s, started_s, ended_s, status, backend, options_json, goal_json, outcome, "
        "n_steps) VALUES (?, 1.0, 2.0, 3.0, 'finished', 'scripted', '{}', '{}', 'unscored', 2)",
        (OLD_RUN,),
    )
    for step in range(2):
        con.execute(
            "INSERT INTO steps VALUES (?, ?, 2.5, 1, 0.25, 0.0, 0.0, 'explore', 'frontier (new)', 4.5, 10.0, 0, 3, "
            "1.0, 2.0, 'frontier', NULL, '{\"total\": 12.0}', 1, 120.0, NULL)",
            (OLD_RUN, step),
        )
    con.commit()
    con.close()


# --- a field added in one place ---------------------------------------------------------------


@dataclasses.dataclass(frozen=True, slots=True)
class RowWithCandidates(StepRow):
    """The one line a new field needs (here: how many goal candidates the agent holds)."""

    candidates_held: int = step_field(INTEGER, lambda s: 0 if s.record is None else len(s.record.candidates), default=0)


def test_a_field_declared_once_reaches_the_table_the_api_the_events_trajectory_and_the_replay(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    schema = StepSchema.of(RowWithCandidates)
    previous_database(tmp_path / "console.sqlite3")  # an older data directory: migrated on open
    monkeypatch.setattr(console.context, "RunStore", functools.partial(RunStore, step_schema=schema))
    con = Console(
        ConsoleConfig(data_dir=tmp_path, viewer=None, allowed_hosts=("testserver",)),
        {"scripted": ScriptedProvider(stop_after=6)},
    )
    sse: list[dict[str, Any]] = []
    publish = con.hub.publish

    def spy(kind: str, run_id: str | None, data: Any) -> Any:  # every step event, as its SSE text
        event = publish(kind, run_id, data)
        if kind == "step":
            sse.append(json.loads(event.to_sse().split("data: ", 1)[1]))
        return event

    con.hub.publish = spy  # type: ignore[method-assign]
    client = TestClient(create_app(con))
    with client:
        photo = ("g.jpg", encode(textured_rgb(120, 160), "JPEG"), "image/jpeg")
        run_id = client.post("/api/runs", files={"goal_image": photo}).json()["id"]
        done = poll(lambda: client.get(f"/api/runs/{run_id}").json(), lambda r: r["status"] == "finished")
        api = client.get(f"/api/runs/{run_id}", params={"steps": True}).json()["steps"]
        trajectory = client.get(done["artifacts"]["trajectory.json"]).json()["steps"]
        timeline = client.get(f"/api/runs/{run_id}/replay").json()["steps"]
        replay_step = client.get(f"/api/runs/{run_id}/replay/4").json()
        old = client.get(f"/api/runs/{OLD_RUN}", params={"steps": True}).json()["steps"]
        stored = con.store.steps(run_id)
    con.close()

    # the scripted agent holds a candidate from its fourth action on
    expected = [0, 0, 0, 1, 1, 1, 1]
    raw = sqlite3.connect(tmp_path / "console.sqlite3")
    assert [
        r[0] for r in raw.execute("SELECT candidates_held FROM steps WHERE run_id=? ORDER BY step", (run_id,))
    ] == expected
    assert {"candidates_held", "event"} <= {r[1] for r in raw.execute("PRAGMA table_info(steps)")}
    raw.close()
    assert [s.candidates_held for s in stored] == expected  # type: ignore[attr-defined]
    assert [s["candidates_held"] for s in api] == expected
    assert [s["candidates_held"] for s in trajectory] == expected
    assert [{k: v for k, v in e.items() if k not in ("seq", "kind", "run_id", "status")} for e in sse] == api
    assert [s["candidates_held"] for s in timeline] == expected and replay_step["candidates_held"] == 1
    # and AgentRecord.event, the field this schema was made for, everywhere too
    assert [s["event"] for s in api] == ["frontier"] * 6 + ["stop_at_goal"] == [s["event"] for s in timeline]
    # the run written by the previous schema reads with the new fields' defaults
    assert [(s["candidates_held"], s["event"], s["reid_full_matcher"], s["timings"]) for s in old] == [
        (0, None, True, {"total": 12.0})
    ] * 2


def test_every_field_round_trips_from_the_agent_to_sqlite_json_and_back_to_a_record(tmp_path: Path) -> None:
    """Each ``agent_field`` of the real ``StepRow`` gets a value unlike its default; all of them
    survive the step -> row -> SQLite -> row -> JSON -> replayed ``AgentRecord`` trip."""
    given: dict[str, Any] = {}
    for k, c in enumerate(STEP_SCHEMA.columns):
        if c.agent_attr is None:
            continue
        if c.type is TEXT:
            given[c.agent_attr] = f"{c.name} {k}"
        elif c.type is REAL:
            given[c.agent_attr] = 0.5 + k
        elif c.type is BOOL:
            given[c.agent_attr] = not c.default
        elif c.type is NAMES:
            given[c.agent_attr] = ("side_step", f"{c.name} {k}")
        else:
            raise AssertionError(f"no test value for {c.name} ({c.type.sql})")
    assert "event" in given and "context" in given
    record = AgentRecord(
        step=7, action=Action.TURN_LEFT, pose=Pose2D(1.0, -2.0, 0.5), timings_ms={"total": 3.25},
        goal_points_xyz=np.zeros((4, 3), np.float32), target_xy_m=(np.float32(1.5), 2.5), **given,
    )  # fmt: skip
    rgb = np.zeros((8, 8, 3), np.uint8)
    rec = StepRecord(
        "abcdefabcdef", 7, time.time(), Action.TURN_LEFT, record.pose, rgb, np.zeros((8, 8), np.float32),
        SIM_INTRINSICS, 1.3, 0.0, rgb, record, np.zeros((8, 2)), step_ms=40.0,
    )  # fmt: skip
    row = STEP_SCHEMA.from_step(rec)
    assert {c.name: getattr(row, c.name) for c in STEP_SCHEMA.columns if c.agent_attr} == {
        c.name: given[c.agent_attr] for c in STEP_SCHEMA.columns if c.agent_attr
    }
    assert (row.n_goal_points, row.target_x_m, row.target_y_m, row.action) == (4, 1.5, 2.5, 2)
    assert type(row.target_x_m) is float and row.timings == {"step_ms": 40.0, "total": 3.25}

    store = RunStore(tmp_path / "db.sqlite3")
    store.create_run("abcdefabcdef", backend="sim", options={}, goal={}, target=None, created_s=1.0)
    store.add_step("abcdefabcdef", row)
    assert store.steps("abcdefabcdef") == [row]
    (as_json,) = store.steps_json("abcdefabcdef")
    assert set(as_json) == {c.name for c in STEP_SCHEMA.columns} | {"action_name"}
    assert as_json == json.loads(json.dumps(as_json))  # plain JSON
    again = AgentRecord(step=7, action=Action.TURN_LEFT, pose=record.pose, **STEP_SCHEMA.record_fields(as_json))
    assert {a: getattr(again, a) for a in given} == given


def test_a_step_without_an_agent_record_uses_the_defaults() -> None:
    rgb = np.zeros((8, 8, 3), np.uint8)
    rec = StepRecord(
        "abcdefabcdef", 0, 5.0, Action.STOP, Pose2D(), rgb, np.zeros((8, 8), np.float32), SIM_INTRINSICS, 1.3, 0.0,
        rgb, None, np.zeros((1, 2)), step_ms=2.0,
    )  # fmt: skip
    row = STEP_SCHEMA.from_step(rec)
    assert (row.mode, row.reason, row.goal_detected, row.n_goal_points, row.event) == ("", "", False, 0, None)
    assert row.timings == {"step_ms": 2.0} and STEP_SCHEMA.to_json(row)["action_name"] == "STOP"


def test_the_generated_table_and_its_rules() -> None:
    ddl = {c.name: c.ddl() for c in STEP_SCHEMA.columns}
    assert ddl["step"] == "step INTEGER NOT NULL"  # no default: one of the first columns
    assert ddl["mode"] == "mode TEXT NOT NULL DEFAULT ''"
    assert ddl["goal_detected"] == "goal_detected INTEGER NOT NULL DEFAULT 0"
    assert ddl["timings"] == "timings_json TEXT NOT NULL DEFAULT '{}'"
    assert ddl["event"] == "event TEXT"
    con = sqlite3.connect(":memory:")
    assert STEP_SCHEMA.migrate(con) == []  # a new file: created whole
    con.close()

    # a column without a default (a dataclass cannot append one, but a reordered definition could)
    must = Column("must", "must", REAL, lambda s: 1.0, nullable=False, default=dataclasses.MISSING, agent_attr=None)
    old = sqlite3.connect(":memory:")
    old.executescript(PREVIOUS_SCHEMA_SQL)
    with pytest.raises(SchemaError, match="must"):
        dataclasses.replace(STEP_SCHEMA, columns=(*STEP_SCHEMA.columns, must)).migrate(old)
    old.close()

    @dataclasses.dataclass(frozen=True, slots=True)
    class Undeclared(StepRow):
        loose: int = 0  # not declared with step_field: nothing would know how to store it

    with pytest.raises(SchemaError, match="loose"):
        StepSchema.of(Undeclared)


def test_a_previous_database_opens_and_gains_the_event(tmp_path: Path) -> None:
    db = tmp_path / "console.sqlite3"
    previous_database(db)
    store = RunStore(db)
    old = store.steps(OLD_RUN)
    assert [(s.step, s.event, s.reid_full_matcher, s.reid_gate_score, s.goal_detected) for s in old] == [
        (0, None, True, 120.0, False),
        (1, None, True, 120.0, False),
    ]
    store.add_step(OLD_RUN, dataclasses.replace(old[1], step=2, event="stop_at_goal"))
    assert [s.event for s in store.steps(OLD_RUN)] == [None, None, "stop_at_goal"]
    store.close()
    assert [s.event for s in RunStore(db).steps(OLD_RUN)] == [None, None, "stop_at_goal"]  # opens again as is
