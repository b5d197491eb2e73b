"""The agent's memory of the robot's home (console/robot_memory.py, issue 31): the rule that drops
it when the robot's map frame cannot be trusted, the robot's home key and file members, and the
backend wrapper that puts a run in the memory's frame, drops it with a message and records where
the run left the base (a stand-in backend: the real one against the fake robot is in
tests/integration/robot/test_robot_memory.py)."""

from __future__ import annotations

import io
import itertools
import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from agent.config import AgentConfig
from agent.types import Action, BackendError, Observation, Pose2D
from console.home_memory import HOME_KEY, HomeMemories, home_key, robot_key
from console.memory_file import (
    DropNote,
    MemoryFileError,
    RobotFrame,
    memory_bytes,
    memory_file_from_bytes,
    memory_from_bytes,
)
from console.robot_memory import (
    MOVED_LIMIT_M,
    MOVED_LIMIT_RAD,
    RobotInHome,
    end_drop_reason,
    end_frame,
    refused_start_reason,
    start_drop_reason,
)
from robot.backend import MapFrameReport
from tests.helpers.agent_scenes import observation

CONFIG = AgentConfig()
KEY = robot_key("192.168.1.15", 4401, 4402, 4403)
STEPS = itertools.count(100, 10)
LEFT = RobotFrame(Pose2D(2.0, 1.0, 0.5), last_step=57, run_id="0123456789ab")


def report(start: Pose2D | None = None, **kw: Any) -> MapFrameReport:
    base = {"last_map": start, "moving_to": None, "runstopped_states": 0, "first_step": 57, "last_step": 59}
    return MapFrameReport(start_map=start, **(base | kw))


# --- the rule --------------------------------------------------------------------------------


def test_the_memory_is_kept_only_where_the_last_run_left_the_robot() -> None:
    at = LEFT.end_map
    assert start_drop_reason(LEFT, True, report(at)) is None
    near = at.compose(Pose2D(0.9 * MOVED_LIMIT_M, 0.0, 0.9 * MOVED_LIMIT_RAD))
    assert start_drop_reason(LEFT, True, report(near)) is None  # localisation jitter, a move's tolerance
    pushed = at.compose(Pose2D(0.0, 1.1 * MOVED_LIMIT_M, 0.0))
    why = start_drop_reason(LEFT, True, report(pushed))
    assert why is not None and "0.33 m and 0 deg from where run 0123456789ab left it" in why and "by hand" in why
    turned = Pose2D(at.x_m, at.y_m, at.yaw_rad - 1.1 * MOVED_LIMIT_RAD)
    assert "22 deg" in (start_drop_reason(LEFT, True, report(turned)) or "")
    across = Pose2D(at.x_m, at.y_m, math.pi - 0.01)  # headings compared on the circle
    assert (
        start_drop_reason(RobotFrame(Pose2D(at.x_m, at.y_m, -math.pi + 0.01), 57, None), True, report(across)) is None
    )
    reset = start_drop_reason(LEFT, True, report(Pose2D()))  # localisation started again at the origin
    assert reset is not None and "2.24 m" in reset and "localisation was reset" in reset


def test_a_runstop_a_restarted_bridge_or_no_record_drops_it_and_nothing_remembered_keeps_nothing() -> None:
    at = LEFT.end_map
    runstop = start_drop_reason(LEFT, True, report(at, runstopped_states=3))
    assert runstop is not None and "runstopped at the start" in runstop and "pushed by hand" in runstop
    restarted = start_drop_reason(LEFT, True, report(at, first_step=-1))
    assert restarted is not None and "started again" in restarted and "step -1 now, step 57 then" in restarted
    assert start_drop_reason(replace(LEFT, last_step=None), True, report(at, first_step=-1)) is None  # not said
    assert start_drop_reason(LEFT, True, report(at, first_step=None)) is None
    assert "no record" in (start_drop_reason(None, True, report(at)) or "")
    for previous in (None, LEFT):  # nothing remembered: nothing to drop, whatever happened
        assert start_drop_reason(previous, False, report(Pose2D(), runstopped_states=1, first_step=-1)) is None


def test_what_a_refused_start_and_a_runs_end_say_about_the_frame() -> None:
    assert "runstopped" in (refused_start_reason("runstopped") or "")
    assert "powered off" in (refused_start_reason("not_homed") or "")
    for code in ("disconnected", "ack_timeout", "head_failed", "cancelled"):
        assert refused_start_reason(code) is None
    end = report(Pose2D(1.0, 0.0, 0.0), runstopped_states=2)
    assert end_drop_reason(end, runstops_at_start=2) is None  # seen before the start was fixed
    assert "during this run" in (end_drop_reason(end, runstops_at_start=0) or "")
    assert end_frame(end, "0123456789ab") == RobotFrame(Pose2D(1.0, 0.0, 0.0), 59, "0123456789ab")
    goal = Pose2D(1.25, 0.0, 0.0)  # the run ended during a move: the base goes on to its goal
    assert end_frame(replace(end, moving_to=goal), None) == RobotFrame(goal, 59, None)
    assert end_frame(report(None), None) is None


# --- the key and the file ------------------------------------------------------------------------


def test_the_robots_home_key_is_stable_per_address_and_the_simulator_keys_are_unchanged() -> None:
    assert KEY == robot_key("192.168.1.15", 4401, 4402, 4403) and HOME_KEY.match(KEY)
    others = {robot_key("192.168.1.16", 4401, 4402, 4403), robot_key("192.168.1.15", 5401, 4402, 4403)}
    assert KEY not in others and len(others) == 2
    assert [home_key("home", 3), home_key("scene", 12)] == ["home-3", "scene-12"]
    for bad in ("robot-", "robot-XYZ0123456", "robot-0123456789abc", "robot-../x", "home-x"):
        assert not HOME_KEY.match(bad), bad


def filled() -> Any:
    from agent.memory import HomeMemory

    mem = HomeMemory(CONFIG.memory)
    grid = mem.begin_goal(CONFIG.mapping, "xfeat")
    grid.layers.obstacle[3, 4:9] = True
    return mem


def test_a_robot_homes_file_keeps_where_the_base_was_left_and_the_last_drop() -> None:
    note = DropNote("the robot was runstopped during this run", 1.7e9, "ba9876543210")
    data = memory_bytes(filled(), Pose2D(1.0, 2.0, 0.3), LEFT, note)
    back = memory_file_from_bytes(data, CONFIG.memory, CONFIG.mapping, "xfeat")
    assert (back.anchor_world, back.robot_frame, back.dropped) == (Pose2D(1.0, 2.0, 0.3), LEFT, note)
    assert back.memory.grid is not None and back.memory.grid.layers.obstacle[3, 4:9].all()
    mem, anchor = memory_from_bytes(data, CONFIG.memory, CONFIG.mapping, "xfeat")  # the reader before stays
    assert anchor == Pose2D(1.0, 2.0, 0.3) and mem.goal_index == 0
    plain = memory_file_from_bytes(memory_bytes(filled(), None), CONFIG.memory, CONFIG.mapping, "xfeat")
    assert (plain.robot_frame, plain.dropped) == (None, None)  # a simulator home's file has neither
    with np.load(io.BytesIO(data), allow_pickle=False) as z:
        meta = json.loads(z["meta"].tobytes().decode())
    assert meta["format"] == 2  # not bumped: the members are optional
    meta["robot_frame"]["run_id"] = "../../etc"
    buf = io.BytesIO()
    with np.load(io.BytesIO(data), allow_pickle=False) as z:
        arrays = {n: z[n] for n in z.files if n != "meta"}
    np.savez(buf, meta=np.frombuffer(json.dumps(meta).encode(), np.uint8), **arrays)
    with pytest.raises(MemoryFileError, match="not a run id"):
        memory_file_from_bytes(buf.getvalue(), CONFIG.memory, CONFIG.mapping, "xfeat")


# --- the backend in the memory's frame -----------------------------------------------------------


@dataclass
class StandIn:
    """A robot backend that reports what it is told (``StretchBackend``'s shape)."""

    start_map: Pose2D
    refuse: str | None = None  # a BackendError reason at reset
    runstops_at_start: int = 0
    runstops_later: int = 0
    first_step: int = field(default_factory=lambda: next(STEPS))  # the bridge counts on between runs
    moved: Pose2D = field(default_factory=Pose2D)  # relative to the start, after the run's moves
    closed: bool = False
    cancelled: str | None = None
    _reset: bool = False

    def reset(self) -> Observation:
        if self.refuse is not None:
            raise BackendError(self.refuse, "refused")
        self._reset = True
        return observation([], Pose2D())

    def observe(self) -> Observation:
        return observation([], self.moved, step=1)

    def apply(self, action: Action) -> None:
        pass

    def cancel(self, why: str = "") -> None:
        self.cancelled = why

    def close(self) -> None:
        self.closed = True

    @property
    def map_frame(self) -> MapFrameReport:
        runstops = self.runstops_at_start + (self.runstops_later if self.closed else 0)
        last = self.start_map.compose(self.moved) if self._reset else self.start_map
        return MapFrameReport(
            self.start_map if self._reset else None, last, None, runstops, self.first_step, self.first_step + 5
        )


class Run:
    """One console run on the robot with its home's memory (what ``StretchProvider.open`` wires)."""

    def __init__(self, store: HomeMemories, backend: StandIn, run_id: str) -> None:
        self.store, self.backend = store, backend
        self.slot = store.acquire(KEY, run_id)
        self.notes: list[str] = []
        self.config: dict[str, Any] = {}
        self.robot = RobotInHome(backend, store, self.slot, run_id, self.config, self.notes.append)  # type: ignore[arg-type]

    def go(self, add: bool = True) -> Observation | None:
        """reset, the agent's goal (a map cell where it stands), one observation, close, finish."""
        try:
            obs = self.robot.reset()
            if add:
                grid = self.slot.memory.begin_goal(CONFIG.mapping, "xfeat")
                grid.layers.obstacle[grid.cell_of(obs.pose)] = True
            return self.robot.observe()
        except BackendError:
            return None
        finally:
            self.robot.close()
            self.robot.finish()


def test_runs_share_the_memory_in_the_first_starts_frame_and_a_moved_robot_drops_it(tmp_path: Path) -> None:
    store = HomeMemories(tmp_path / "memory", CONFIG.memory, CONFIG.mapping, "xfeat")
    a = Pose2D(1.0, 2.0, math.pi / 2)
    first = Run(store, StandIn(a, moved=Pose2D(0.5, 0.0, 0.0)), "aaaaaaaaaaaa")
    obs = first.go()
    assert first.config == {"memory_origin": [0.0, 0.0, 0.0]} and first.notes == []
    assert obs is not None and obs.pose == Pose2D(0.5, 0.0, 0.0)
    path = store.path(KEY)
    assert path.is_file() and store.slot(KEY).anchor_world == a
    left = store.slot(KEY).robot_frame
    assert left is not None and left.run_id == "aaaaaaaaaaaa" and left.end_map.distance_to(a.compose(obs.pose)) < 1e-9

    b = left.end_map  # the next run starts where the first left the robot
    second = Run(store, StandIn(b, moved=Pose2D(0.0, 0.0, math.radians(30))), "bbbbbbbbbbbb")
    memory = second.slot.memory
    second.robot.cancel("stop")
    assert second.robot.backend.cancelled == "stop"  # the run manager's stop reaches the robot
    obs = second.go()
    origin = b.relative_to(a)
    assert second.notes == [] and second.config["memory_origin"] == pytest.approx([0.5, 0.0, 0.0])
    assert obs is not None and obs.pose.distance_to(origin) < 1e-9  # InHomeFrame: the origin composed
    assert obs.pose.yaw_rad == pytest.approx(math.radians(30))
    assert memory.goal_index == 1 and len(memory.goals) == 2  # the same memory, a second goal

    c = Pose2D(b.x_m + 1.0, b.y_m, b.yaw_rad)  # moved by hand between runs
    third = Run(store, StandIn(c), "cccccccccccc")
    kept = third.slot.memory
    obs = third.go(add=False)
    assert third.slot.memory is kept and kept.grid is None and kept.goals == []  # emptied in place
    assert third.config["memory_origin"] == [0.0, 0.0, 0.0] and obs is not None and obs.pose == Pose2D()
    assert "moved by hand" in third.config["memory_dropped"]
    (note,) = third.notes
    assert note.startswith(f"the memory of {KEY} is dropped: the robot starts 1.00 m") and "starts from nothing" in note
    dropped = store.summary(KEY)["dropped"]
    assert dropped["run_id"] == "cccccccccccc" and "1.00 m" in dropped["reason"]
    assert store.slot(KEY).anchor_world == c  # the dropped memory's new frame: this start
    assert HomeMemories(tmp_path / "memory", CONFIG.memory, CONFIG.mapping, "xfeat").summary(KEY)["dropped"] == dropped


def test_a_runstop_at_the_start_or_during_a_run_drops_the_memory_once(tmp_path: Path) -> None:
    store = HomeMemories(tmp_path / "memory", CONFIG.memory, CONFIG.mapping, "xfeat")
    a = Pose2D(0.0, 0.0, 0.0)
    Run(store, StandIn(a), "aaaaaaaaaaaa").go()
    refused = Run(store, StandIn(a, refuse="runstopped", runstops_at_start=5), "bbbbbbbbbbbb")
    assert refused.go() is None  # the run fails, as before
    (note,) = refused.notes
    assert "runstopped at the start of this run" in note and "this run fails at its start" in note
    assert store.summary(KEY)["goals"] == [] and store.slot(KEY).memory.grid is None
    assert store.summary(KEY)["dropped"]["run_id"] == "bbbbbbbbbbbb"

    fresh = Run(store, StandIn(Pose2D(3.0, 0.0, 0.0)), "cccccccccccc")
    fresh.go()  # from nothing: nothing to check, no message
    assert fresh.notes == [] and fresh.config["memory_origin"] == [0.0, 0.0, 0.0]
    assert store.summary(KEY)["goals"] != []
    during = Run(store, StandIn(Pose2D(3.0, 0.0, 0.0), runstops_later=2), "dddddddddddd")
    during.go()
    (note,) = during.notes
    assert "runstopped during this run" in note and "the next run starts from nothing" in note
    assert store.summary(KEY)["goals"] == [] and store.slot(KEY).robot_frame is None
    flicker = Run(store, StandIn(Pose2D(3.0, 0.0, 0.0), runstops_at_start=1), "eeeeeeeeeeee")
    flicker.go()  # nothing remembered when the runstop was seen: nothing to say; then one goal
    assert flicker.notes == [] and store.summary(KEY)["goals"] != []  # seen before its start: kept
