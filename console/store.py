"""The console's run records: one SQLite file under the data directory.

Tables
------
runs   one row per run: goal photo (path + hashes), backend and options, agent
       configuration, status, outcome, metrics and timings (JSON columns).
steps  one row per agent step: its columns, migration, insert and select are generated from
       the one step definition (``console.step_schema.StepRow``).
replay_steps, replay_maps   what a replay needs (console.replay): a JPEG thumbnail and a
       small JSON per step, the agent's map every few steps.

Everything is written through one connection guarded by a lock (the worker
thread writes steps while request handlers read). WAL mode lets readers go on
while a step is being written. On open, any run still marked active is marked
``interrupted``: the process that owned it is gone.
"""

from __future__ import annotations

import json
import logging
import sqlite3
import threading
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from console.jsonio import dumps as _dump
from console.step_schema import STEP_SCHEMA, StepRow, StepSchema

logger = logging.getLogger(__name__)

SCHEMA_VERSION = 2  # 2: replay tables (older files gain them on open)

# Run status values. ``pending``/``running`` are active; the rest are final.
ACTIVE_STATUSES = ("pending", "running", "stopping")
FINAL_STATUSES = ("finished", "stopped", "failed", "interrupted")

_SCHEMA = """
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

_JSON_COLUMNS = {
    "options_json": "options",
    "agent_json": "agent_config",
    "goal_json": "goal",
    "target_json": "target",
    "metrics_json": "metrics",
    "timings_json": "timings",
}


class RunStore:
    """SQLite-backed run records. Thread-safe; one instance per data directory."""

    def __init__(self, db_path: Path, step_schema: StepSchema = STEP_SCHEMA) -> None:
        """``step_schema``: the steps table's definition (``console.step_schema``; tests extend it)."""
        self.db_path = Path(db_path)
        self.step_schema = step_schema
        self.db_path.parent.mkdir(parents=True, exist_ok=True)
        self._lock = threading.RLock()
        self._db = sqlite3.connect(str(self.db_path), check_same_thread=False, isolation_level=None)
        self._db.row_factory = sqlite3.Row
        with self._lock:
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute("PRAGMA foreign_keys=ON")
            self._db.execute("PRAGMA synchronous=NORMAL")
            self._db.executescript(_SCHEMA)
            # the steps table from the one step definition; an older file gains the fields it lacks
            added = self.step_schema.migrate(self._db)
            if added:
                logger.info("%s: the steps table gained %s", self.db_path, ", ".join(added))
            self._db.execute(
                "INSERT OR IGNORE INTO meta (key, value) VALUES ('schema_version', ?)", (str(SCHEMA_VERSION),)
            )

    # --- lifecycle ---------------------------------------------------------

    def mark_interrupted(self) -> list[str]:
        """Mark runs left active by a previous process as interrupted; returns their ids."""
        with self._lock:
            rows = self._db.execute(
                f"SELECT id FROM runs WHERE status IN ({','.join('?' * len(ACTIVE_STATUSES))})", ACTIVE_STATUSES
            ).fetchall()
            ids = [r["id"] for r in rows]
            for run_id in ids:
                # The run ended when its process did, not now: its last recorded step is the
                # best evidence of when (else its start, else its creation).
                self._db.execute(
                    "UPDATE runs SET status='interrupted', outcome='interrupted', "
                    "outcome_detail='the console stopped while this run was active', "
                    "ended_s=COALESCE((SELECT MAX(t_s) FROM steps WHERE steps.run_id=runs.id), started_s, created_s) "
                    "WHERE id=?",
                    (run_id,),
                )
        if ids:
            logger.warning("marked %d run(s) interrupted by the last shutdown: %s", len(ids), ", ".join(ids))
        return ids

    def close(self) -> None:
        with self._lock:
            self._db.close()

    # --- runs --------------------------------------------------------------

    def create_run(
        self,
        run_id: str,
        *,
        backend: str,
        options: Mapping[str, Any],
        goal: Mapping[str, Any],
        target: Mapping[str, Any] | None,
        created_s: float,
    ) -> None:
        with self._lock:
            self._db.execute(
                "INSERT INTO runs (id, created_s, status, backend, options_json, goal_json, target_json) "
                "VALUES (?, ?, 'pending', ?, ?, ?, ?)",
                (run_id, created_s, backend, _dump(options), _dump(goal), _dump(target) if target else None),
            )

    def update_run(self, run_id: str, **fields: Any) -> None:
        """Update columns; JSON columns are given by their short names (``metrics=...``)."""
        if not fields:
            return
        columns = []
        values: list[Any] = []
        reverse = {short: col for col, short in _JSON_COLUMNS.items()}
        allowed = {"started_s", "ended_s", "status", "outcome", "outcome_detail", "n_steps", "error"}
        for key, value in fields.items():
            if key in reverse:
                columns.append(f"{reverse[key]}=?")
                values.append(_dump(value) if value is not None else None)
            elif key in allowed:
                columns.append(f"{key}=?")
                values.append(value)
            else:
                raise KeyError(f"unknown run column {key!r}")
        values.append(run_id)
        with self._lock:
            self._db.execute(f"UPDATE runs SET {', '.join(columns)} WHERE id=?", values)

    def get_run(self, run_id: str) -> dict[str, Any] | None:
        with self._lock:
            row = self._db.execute("SELECT * FROM runs WHERE id=?", (run_id,)).fetchone()
        return _run_dict(row) if row is not None else None

    def list_runs(
        self,
        limit: int = 100,
        offset: int = 0,
        *,
        outcome: str | None = None,
        status: str | None = None,
        backend: str | None = None,
        home: str | None = None,
    ) -> list[dict[str, Any]]:
        """Newest first; each filter given must match exactly (``home``: the options' home id)."""
        where, values = [], []
        for column, value in (("outcome", outcome), ("status", status), ("backend", backend)):
            if value is not None:
                where.append(f"{column}=?")
                values.append(value)
        if home is not None:
            where.append("json_extract(options_json, '$.home')=?")
            values.append(home)
        clause = f"WHERE {' AND '.join(where)} " if where else ""
        with self._lock:
            rows = self._db.execute(
                f"SELECT * FROM runs {clause}ORDER BY created_s DESC LIMIT ? OFFSET ?",
                (*values, int(limit), int(offset)),
            ).fetchall()
        return [_run_dict(r) for r in rows]

    # --- steps -------------------------------------------------------------

    def add_step(self, run_id: str, row: StepRow) -> None:
        with self._lock:
            self.step_schema.insert(self._db, run_id, row)
            self._db.execute("UPDATE runs SET n_steps=? WHERE id=?", (row.step + 1, run_id))

    # --- replay (console.replay) ---------------------------------------------------

    def add_replay_step(self, run_id: str, step: int, frame_jpeg: bytes, extras_json: str) -> None:
        with self._lock:
            self._db.execute(
                "INSERT OR REPLACE INTO replay_steps VALUES (?,?,?,?)", (run_id, int(step), frame_jpeg, extras_json)
            )

    def add_replay_map(self, run_id: str, step: int, map_blob: bytes) -> None:
        with self._lock:
            self._db.execute("INSERT OR REPLACE INTO replay_maps VALUES (?,?,?)", (run_id, int(step), map_blob))

    def replay_frame(self, run_id: str, step: int) -> bytes | None:
        with self._lock:
            row = self._db.execute(
                "SELECT frame_jpeg FROM replay_steps WHERE run_id=? AND step=?", (run_id, int(step))
            ).fetchone()
        return None if row is None else bytes(row["frame_jpeg"])

    def replay_extras(self, run_id: str) -> dict[int, dict[str, Any]]:
        with self._lock:
            rows = self._db.execute(
                "SELECT step, extras_json FROM replay_steps WHERE run_id=? ORDER BY step", (run_id,)
            ).fetchall()
        return {int(r["step"]): json.loads(r["extras_json"]) for r in rows}

    def replay_map_at(self, run_id: str, step: int) -> tuple[int, bytes] | None:
        """The latest map snapshot at or before ``step``."""
        with self._lock:
            row = self._db.execute(
                "SELECT step, map_blob FROM replay_maps WHERE run_id=? AND step<=? ORDER BY step DESC LIMIT 1",
                (run_id, int(step)),
            ).fetchone()
        return None if row is None else (int(row["step"]), bytes(row["map_blob"]))

    def replay_latest_step(self, run_id: str) -> int | None:
        with self._lock:
            # a step with both its row and its pictures (the two are written one after the other)
            row = self._db.execute(
                f"SELECT MAX(r.step) m FROM replay_steps r JOIN {self.step_schema.table} s "
                "ON s.run_id=r.run_id AND s.step=r.step WHERE r.run_id=?",
                (run_id,),
            ).fetchone()
        return None if row is None or row["m"] is None else int(row["m"])

    def replay_map_steps(self, run_id: str) -> list[int]:
        with self._lock:
            rows = self._db.execute("SELECT step FROM replay_maps WHERE run_id=? ORDER BY step", (run_id,)).fetchall()
        return [int(r["step"]) for r in rows]

    def replay_bytes(self, run_id: str) -> dict[str, int]:
        """Stored replay sizes: frames, per-step JSON, maps (bytes)."""
        with self._lock:
            a = self._db.execute(
                "SELECT COALESCE(SUM(LENGTH(frame_jpeg)),0) f, COALESCE(SUM(LENGTH(extras_json)),0) e, COUNT(*) n "
                "FROM replay_steps WHERE run_id=?",
                (run_id,),
            ).fetchone()
            b = self._db.execute(
                "SELECT COALESCE(SUM(LENGTH(map_blob)),0) m, COUNT(*) n FROM replay_maps WHERE run_id=?", (run_id,)
            ).fetchone()
        return {
            "frames": int(a["f"]),
            "extras": int(a["e"]),
            "steps": int(a["n"]),
            "maps": int(b["m"]),
            "n_maps": int(b["n"]),
        }

    def steps(self, run_id: str) -> list[StepRow]:
        with self._lock:
            return self.step_schema.select(self._db, run_id)

    def steps_json(self, run_id: str) -> list[dict[str, Any]]:
        """The run's steps as the API, the event stream and trajectory.json carry them."""
        return self.step_schema.to_json_rows(self.steps(run_id))


def _run_dict(row: sqlite3.Row) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key in row.keys():  # noqa: SIM118 - iterating a sqlite3.Row gives its values
        value = row[key]
        if key in _JSON_COLUMNS:
            out[_JSON_COLUMNS[key]] = json.loads(value) if value is not None else None
        else:
            out[key] = value
    return out
