"""The one definition of a step as the console keeps and shows it.

``StepRow`` declares every field once, with a small spec (``step_field`` or ``agent_field``): its
SQL type and how its value is read from a step (``StepRecord``: the loop's step and the agent's
``AgentRecord``). ``StepSchema.of(StepRow)`` generates everything else from it:

* the ``steps`` table: CREATE TABLE, the migration of an older file (ALTER TABLE ADD COLUMN for
  each field its table lacks), the INSERT and the SELECT -> row (``console.store``);
* the row of a step (``from_step``: the run manager, the live viewer's words);
* the JSON of a step (``to_json``): the API's steps, the event stream's step events,
  trajectory.json and the replay timeline all carry exactly this;
* the agent's record rebuilt from a stored step for the viewer's replay (``record_fields``).

So adding a field to the record is one line in ``StepRow`` (an ``agent_field`` when it copies an
``AgentRecord`` attribute). The rules the generator follows: a field whose default is None is a
nullable column; a field with any other default is NOT NULL DEFAULT that value, so an older file
can gain it; a field without a default is one of the first columns, which every file has.
"""

from __future__ import annotations

import dataclasses
import enum
import json
import sqlite3
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from agent.types import Action
from console.jsonio import dumps, json_safe

if TYPE_CHECKING:
    from console.session import StepRecord

Reader = Callable[["StepRecord"], Any]

_SPEC_KEY = "console.step_schema"  # the key of a field's ``ColumnSpec`` in its dataclass metadata
_NO_DEFAULT: Any = dataclasses.MISSING


def _text(value: Any) -> str:
    # the agent's enums (modes, events) are stored by value: "explore", not "Mode.EXPLORE"
    return str(value.value) if isinstance(value, enum.Enum) else str(value)


@dataclass(frozen=True, slots=True)
class SqlType:
    """How a field is stored. ``normalise``: a value read from a step -> the row's value (plain
    Python, never numpy); ``encode``: row -> SQLite; ``decode``: SQLite -> row. None is NULL
    both ways and never converted."""

    sql: str
    normalise: Callable[[Any], Any]
    encode: Callable[[Any], Any]
    decode: Callable[[Any], Any]


INTEGER = SqlType("INTEGER", int, int, int)
REAL = SqlType("REAL", float, float, float)
TEXT = SqlType("TEXT", _text, str, str)
BOOL = SqlType("INTEGER", bool, int, bool)  # SQLite has no boolean: 0 / 1
JSON = SqlType("TEXT", lambda v: v, dumps, json.loads)  # a mapping or list, as a JSON text column
# a tuple of names (enum values), as a JSON list; read back as a tuple, as the agent wrote it
NAMES = SqlType("TEXT", lambda v: tuple(_text(x) for x in v), lambda v: dumps(list(v)), lambda t: tuple(json.loads(t)))


@dataclass(frozen=True, slots=True)
class ColumnSpec:
    """What a ``StepRow`` field declares besides its name, type annotation and default."""

    type: SqlType
    read: Reader
    sql_name: str | None = None  # the column's name when it differs from the field's
    agent_attr: str | None = None  # the ``AgentRecord`` attribute it copies (None: computed)


def step_field(
    type_: SqlType,
    read: Reader,
    *,
    sql_name: str | None = None,
    default: Any = _NO_DEFAULT,
    default_factory: Any = _NO_DEFAULT,
    agent_attr: str | None = None,
) -> Any:
    """A ``StepRow`` field read from the step by ``read`` (``default``: see the module's rules)."""
    spec = ColumnSpec(type_, read, sql_name, agent_attr)
    if default_factory is not _NO_DEFAULT:
        return dataclasses.field(default_factory=default_factory, metadata={_SPEC_KEY: spec})
    return dataclasses.field(default=default, metadata={_SPEC_KEY: spec})


def agent_field(attr: str, type_: SqlType, *, default: Any = None) -> Any:
    """A ``StepRow`` field that copies ``AgentRecord.<attr>`` (``default`` when the agent gave no
    record or left it None)."""

    def read(rec: StepRecord) -> Any:
        value = None if rec.record is None else getattr(rec.record, attr)
        return default if value is None else value

    return step_field(type_, read, default=default, agent_attr=attr)


def _target(axis: int) -> Reader:
    def read(rec: StepRecord) -> float | None:
        target = None if rec.record is None else rec.record.target_xy_m
        return None if target is None else target[axis]

    return read


def _timings(rec: StepRecord) -> dict[str, float]:
    """The step's wall time (act + apply) and the agent's own per-part timings."""
    parts = {} if rec.record is None else {k: float(v) for k, v in rec.record.timings_ms.items()}
    return {"step_ms": rec.step_ms, **parts}


@dataclass(frozen=True, slots=True)
class StepRow:
    """One agent step as the console keeps it (pose in the run's start-relative frame). The one
    definition: the table, its migration, the JSON and the replay are generated from these fields."""

    step: int = step_field(INTEGER, lambda s: s.step)
    t_s: float = step_field(REAL, lambda s: s.t_s)  # wall clock after the action was applied
    action: int = step_field(INTEGER, lambda s: int(s.action))
    x_m: float = step_field(REAL, lambda s: s.pose.x_m)
    y_m: float = step_field(REAL, lambda s: s.pose.y_m)
    yaw_rad: float = step_field(REAL, lambda s: s.pose.yaw_rad)
    mode: str = agent_field("mode", TEXT, default="")
    reason: str = agent_field("reason", TEXT, default="")
    reid_score: float | None = agent_field("reid_score", REAL)
    reid_tau: float | None = agent_field("reid_tau", REAL)
    goal_detected: bool = agent_field("goal_detected", BOOL, default=False)
    n_goal_points: int = step_field(
        INTEGER, lambda s: 0 if s.record is None else len(s.record.goal_points_xyz), default=0
    )
    target_x_m: float | None = step_field(REAL, _target(0), default=None)
    target_y_m: float | None = step_field(REAL, _target(1), default=None)
    target_kind: str | None = agent_field("target_kind", TEXT)
    planner_error: str | None = agent_field("planner_error", TEXT)
    timings: Mapping[str, float] = step_field(JSON, _timings, sql_name="timings_json", default_factory=dict)
    reid_full_matcher: bool | None = agent_field("reid_full_matcher", BOOL)  # False: the gate skipped it
    reid_gate_score: float | None = agent_field("reid_gate_score", REAL)  # the gate's cheap score (None: gate off)
    reid_exit_score: float | None = agent_field("reid_exit_score", REAL)  # LighterGlue's score after its exit layer
    event: str | None = agent_field("event", TEXT)  # the decision's event (agent.events.Event value)
    # what it was decided in (agent.events.Context values, outermost first)
    context: tuple[str, ...] | None = agent_field("context", NAMES)


@dataclass(frozen=True, slots=True)
class Column:
    """One generated column: a ``StepRow`` field with its spec resolved."""

    name: str  # the field's name, also the JSON key
    sql_name: str
    type: SqlType
    read: Reader
    nullable: bool
    default: Any  # _NO_DEFAULT: required (one of the first columns)
    agent_attr: str | None

    def ddl(self) -> str:
        """The column's definition, as in CREATE TABLE and ALTER TABLE ADD COLUMN."""
        if self.nullable:
            return f"{self.sql_name} {self.type.sql}"
        if self.default is _NO_DEFAULT:
            return f"{self.sql_name} {self.type.sql} NOT NULL"
        return f"{self.sql_name} {self.type.sql} NOT NULL DEFAULT {_sql_literal(self.type.encode(self.default))}"


def _convert(value: Any, convert: Callable[[Any], Any]) -> Any:
    return None if value is None else convert(value)


def _sql_literal(value: Any) -> str:
    if isinstance(value, str):
        return "'" + value.replace("'", "''") + "'"
    if isinstance(value, (int, float)):
        return repr(value)
    raise TypeError(f"no SQL literal for a default of type {type(value).__name__}")


class SchemaError(RuntimeError):
    """A ``StepRow`` definition or a stored table the schema cannot work with."""


@dataclass(frozen=True, slots=True)
class StepSchema:
    """Everything generated from a step row class (``StepRow`` or a subclass adding fields)."""

    row_type: type[StepRow]
    columns: tuple[Column, ...]
    table: str = "steps"

    @staticmethod
    def of(row_type: type[StepRow], table: str = "steps") -> StepSchema:
        columns = []
        for f in dataclasses.fields(row_type):
            spec = f.metadata.get(_SPEC_KEY)
            if not isinstance(spec, ColumnSpec):
                raise SchemaError(f"{row_type.__name__}.{f.name} is not declared with step_field or agent_field")
            if f.default_factory is not dataclasses.MISSING:
                default = f.default_factory()
            else:
                default = f.default
            columns.append(
                Column(
                    name=f.name,
                    sql_name=spec.sql_name or f.name,
                    type=spec.type,
                    read=spec.read,
                    nullable=default is None,
                    default=default,
                    agent_attr=spec.agent_attr,
                )
            )
        if "step" not in {c.name for c in columns}:
            raise SchemaError(f"{row_type.__name__} needs a 'step' field (the table's key with the run id)")
        return StepSchema(row_type, tuple(columns), table)

    # --- SQLite ---------------------------------------------------------------

    def create_sql(self) -> str:
        body = ",\n    ".join(
            [
                "run_id TEXT NOT NULL REFERENCES runs (id) ON DELETE CASCADE",
                *(c.ddl() for c in self.columns),
                "PRIMARY KEY (run_id, step)",
            ]
        )
        return f"CREATE TABLE IF NOT EXISTS {self.table} (\n    {body}\n);"

    def migrate(self, db: sqlite3.Connection) -> list[str]:
        """Create the table, or add the columns an older file's table lacks; returns their names."""
        db.executescript(self.create_sql())
        have = {row[1] for row in db.execute(f"PRAGMA table_info({self.table})").fetchall()}
        added = []
        for c in self.columns:
            if c.sql_name in have:
                continue
            if not c.nullable and c.default is _NO_DEFAULT:
                raise SchemaError(
                    f"the {self.table} table lacks {c.sql_name}, which has no default: give the field a default "
                    "(or None) so that older files can gain it"
                )
            db.execute(f"ALTER TABLE {self.table} ADD COLUMN {c.ddl()}")
            added.append(c.sql_name)
        return added

    def insert(self, db: sqlite3.Connection, run_id: str, row: StepRow) -> None:
        names = ", ".join(["run_id", *(c.sql_name for c in self.columns)])
        marks = ",".join("?" * (len(self.columns) + 1))
        values = [run_id, *(_convert(getattr(row, c.name), c.type.encode) for c in self.columns)]
        db.execute(f"INSERT OR REPLACE INTO {self.table} ({names}) VALUES ({marks})", values)

    def select(self, db: sqlite3.Connection, run_id: str) -> list[StepRow]:
        names = ", ".join(c.sql_name for c in self.columns)
        rows = db.execute(f"SELECT {names} FROM {self.table} WHERE run_id=? ORDER BY step", (run_id,)).fetchall()
        return [
            self.row_type(**{c.name: _convert(raw, c.type.decode) for c, raw in zip(self.columns, row)}) for row in rows
        ]

    # --- a step in, JSON out ------------------------------------------------------

    def from_step(self, rec: StepRecord) -> StepRow:
        return self.row_type(**{c.name: _convert(c.read(rec), c.type.normalise) for c in self.columns})

    def to_json(self, row: StepRow) -> dict[str, Any]:
        """The step as JSON (plus the action's name): the API, the event stream and trajectory.json."""
        out: dict[str, Any] = {c.name: getattr(row, c.name) for c in self.columns}
        out["action_name"] = Action(row.action).name
        safe: dict[str, Any] = json_safe(out)
        return safe

    def to_json_rows(self, rows: Iterable[StepRow]) -> list[dict[str, Any]]:
        return [self.to_json(r) for r in rows]

    def record_fields(self, step_json: Mapping[str, Any]) -> dict[str, Any]:
        """``AgentRecord`` keyword arguments from a step's JSON: every field that copies one of
        its attributes (the viewer's replay rebuilds the record the agent gave)."""
        return {
            c.agent_attr: None if step_json[c.name] is None else c.type.normalise(step_json[c.name])
            for c in self.columns
            if c.agent_attr is not None and c.name in step_json
        }


STEP_SCHEMA = StepSchema.of(StepRow)
