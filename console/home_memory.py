"""The console's memory of each home (issue 31; docs/architecture.md section 11).

Runs in the same home share one ``agent.memory.HomeMemory`` (the map, keyframes and earlier
goals): the second request in a home starts from what the first saw. A home's memory is its own,
keyed by the home (``home-<seed>``: a catalogue home of the simulator; ``scene-<seed>``: an
episode's full home; ``robot-<10 hex digits>``: the Stretch the console drives, in its own map
frame, ``robot_key``), and never given to a run in another home.

**The frame.** A memory holds poses and points in one frame, the pose frame of the first run
that filled it (its *anchor*, the world pose of that run's start). Each console simulator run
starts at its own start pose and its backend reports poses relative to it, so a later run's
backend is put in the memory's frame with ``agent.memory.InHomeFrame(backend, origin)``, origin
being this run's start in the anchor's frame (``start_world.relative_to(anchor_world)``). In the
simulator the console knows both true start poses: for the warm home this stands for the
odometry of a robot that keeps its map between requests. On the robot the start poses are the
robot's own, in its map frame (``robot.backend.StretchBackend.map_frame``), and the memory is
dropped whenever that frame cannot be trusted: a runstop, the base moved between runs, the
robot's bridge started again (``console.robot_memory``, which also says what it cannot see). A
robot home's file also keeps where the last run left the base (``RobotFrame``) and why the
memory was last dropped (``DropNote``), as optional members of the JSON; the format is unchanged
(a reader of format 2 ignores them, a simulator home's file has none).

**On disk.** ``<data>/memory/<home>.npz`` (``console.memory_file``: its format, no pickle),
written when a run in the home ends, read lazily the first time the home is asked for; an unreadable
file is logged, moved aside and the home starts with an empty memory.

**The requests and their runs.** The agent begins a goal (``HomeMemory.begin_goal``, in its
``reset``) on the run's worker thread and replaces its summary at every step there, so the
console does not write the summary while the run goes on: the run that holds the memory
(``HomeMemories.acquire(key, run_id)``) owns the goals begun from then on, shown with its id
while it runs (``summary``) and stamped with it when it releases the memory, before the memory
is saved. The console page's memory panel lists the known objects (``known_objects``: each
request whose final candidates were not all rejected) with the goal photo of the run that asked
for each, and starts a request for one again from that photo (``POST /api/runs`` with
``goal_from_run``, refused unless the run is a request this home remembers: ``remembers``).
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import logging
import math
import re
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from agent.types import Pose2D

if TYPE_CHECKING:  # agent.memory imports torch: not before console.agents.passive_openmp_wait
    from agent.mapping import MappingConfig
    from agent.memory import GoalSummary, HomeMemory, MemoryConfig

from console.memory_file import DropNote, MemoryFileError, RobotFrame, memory_bytes, memory_file_from_bytes

logger = logging.getLogger(__name__)

MARK_MERGE_M = 0.5  # known objects closer than this are one mark on the map, numbered with each request
HOME_KEY = re.compile(r"^((home|scene)-\d{1,9}|robot-[0-9a-f]{10})$")


class MemoryInUse(RuntimeError):
    """The home's memory is being used by the active run (HTTP 409 to forget it)."""


def home_key(kind: str, seed: int) -> str:
    """The memory's key of a simulator home: ``home-<seed>`` (catalogue) or ``scene-<seed>`` (episode)."""
    key = f"{kind}-{int(seed)}"
    if not HOME_KEY.match(key):
        raise ValueError(f"no home key {key!r}")
    return key


def robot_key(host: str, obs_port: int, action_port: int, state_port: int) -> str:
    """The memory's key of the robot the console drives at this address: ``robot-`` and 10 hex
    digits of a hash of the host and the bridge's ports (stable across restarts, safe in a file
    name and a URL; a robot at another address is another home)."""
    digest = hashlib.sha256(f"{host}|{int(obs_port)}|{int(action_port)}|{int(state_port)}".encode()).hexdigest()
    return f"robot-{digest[:10]}"


def known_objects(goals: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The objects the memory knows, from its goals as ``HomeMemory.summary`` gives them: each
    request (``goal_index + 1``) whose final candidates were not all rejected, with its run and
    its best such candidate (state, position, best score) and how many there were."""
    out = []
    for g in goals:
        kept = [c for c in g["candidates"] if c["state"] != "rejected"]
        if kept:
            best = max(kept, key=lambda c: c["best_score"])
            out.append(
                {
                    "request": g["goal_index"] + 1,
                    "run_id": g["run_id"],
                    "state": best["state"],
                    "xy_m": best["xy_m"],
                    "best_score": best["best_score"],
                    "candidates": len(kept),
                }
            )
    return out


# --- the memories of the homes ---------------------------------------------------------


@dataclass(eq=False)
class HomeSlot:
    """One home's memory and the world pose of its frame (None until a run fills it); for a robot
    home, where the last run left the base (``robot_frame``) and the last drop (``dropped``)."""

    key: str
    memory: HomeMemory
    anchor_world: Pose2D | None = None
    in_use: bool = False
    lock: threading.Lock = field(default_factory=threading.Lock)
    run_id: str | None = None  # the console run using the memory (module docstring, "The requests")
    run_goals_from: int = 0  # the goals it begins: those from this goal index on
    robot_frame: RobotFrame | None = None
    dropped: DropNote | None = None

    def is_empty(self) -> bool:
        """Nothing remembered: no map, no keyframe, no goal."""
        return self.memory.grid is None and len(self.memory) == 0 and not self.memory.goals

    def run_of(self, goal: GoalSummary) -> str | None:
        """The run that asked for a goal: stamped, or the run using the memory now."""
        if goal.run_id is None and self.in_use and goal.goal_index >= self.run_goals_from:
            return self.run_id
        return goal.run_id

    def origin_for(self, start_world: Pose2D) -> Pose2D:
        """The pose of a run's start in the memory's frame; an empty memory takes this start as
        its frame (module docstring, "The frame")."""
        if self.anchor_world is None or (self.memory.grid is None and len(self.memory) == 0):
            self.anchor_world = start_world
        if start_world == self.anchor_world:  # exactly the identity, as a backend's own start pose is
            return Pose2D()
        return start_world.relative_to(self.anchor_world)


class HomeMemories:
    """The memories of the simulator's homes, one per home key, loaded lazily from
    ``directory`` and saved there when a run ends. Thread-safe: the run's worker uses a memory
    (``acquire`` ... ``release``) while the API reads it."""

    def __init__(self, directory: Path, config: MemoryConfig, mapping: MappingConfig, matcher: str) -> None:
        self.dir = Path(directory)
        self.config = config
        self.mapping = mapping
        self.matcher = matcher
        self._lock = threading.Lock()
        self._slots: dict[str, HomeSlot] = {}

    def path(self, key: str) -> Path:
        if not HOME_KEY.match(key):
            raise ValueError(f"no home key {key!r}")
        return self.dir / f"{key}.npz"

    def slot(self, key: str) -> HomeSlot:
        """The home's memory: the one in use, else read from its file, else a new empty one."""
        from agent.memory import HomeMemory

        path = self.path(key)
        with self._lock:
            slot = self._slots.get(key)
            if slot is None:
                slot = HomeSlot(key, HomeMemory(self.config))
                if path.is_file():
                    try:
                        file = memory_file_from_bytes(path.read_bytes(), self.config, self.mapping, self.matcher)
                        slot.memory, slot.anchor_world = file.memory, file.anchor_world
                        slot.robot_frame, slot.dropped = file.robot_frame, file.dropped
                        logger.info("memory of %s read from %s (%d keyframes)", key, path, len(slot.memory))
                    except (OSError, MemoryFileError) as exc:
                        aside = path.with_name(f"{key}.unreadable-{time.strftime('%Y%m%d-%H%M%S')}.npz")
                        logger.error(
                            "the memory of %s in %s cannot be used (%s): it is moved to %s and %s starts with an "
                            "empty memory",
                            key,
                            path,
                            exc,
                            aside,
                            key,
                        )
                        try:
                            path.replace(aside)
                        except OSError:
                            logger.exception("moving %s aside failed", path)
                self._slots[key] = slot
            return slot

    def acquire(self, key: str, run_id: str | None = None) -> HomeSlot:
        """The home's memory for a run (one run at a time uses it); the goal it begins will be
        noted as asked for by ``run_id`` (the console run; None: none)."""
        slot = self.slot(key)
        with self._lock:
            if slot.in_use:
                raise MemoryInUse(f"the memory of {key} is in use by another run")
            slot.in_use = True
            slot.run_id = run_id
            slot.run_goals_from = slot.memory.goal_index + 1  # begin_goal takes the next index
        return slot

    def release(self, slot: HomeSlot, save: bool = True) -> None:
        """The run has ended (its worker no longer writes the memory): its goals are stamped with
        its id and the memory is saved (errors logged; the memory stays in this process)."""
        try:
            with slot.lock:
                slot.memory.goals = [dataclasses.replace(g, run_id=slot.run_of(g)) for g in slot.memory.goals]
            if save:
                self.save(slot)
        finally:
            with self._lock:
                slot.in_use = False
                slot.run_id = None

    def drop(self, slot: HomeSlot, reason: str, run_id: str | None = None) -> None:
        """Drop a home's memory because its frame can no longer be trusted (``console.robot_memory``),
        while a run holds it (``acquire``): emptied in place, as Forget empties a home (the run's
        agent, which holds this memory, begins from nothing), its file removed, and ``reason``
        kept as the home's last drop (``DropNote``) and logged."""
        path = self.path(slot.key)
        with slot.lock:
            slot.memory.clear()
            slot.anchor_world = None
            slot.robot_frame = None
            slot.dropped = DropNote(reason, time.time(), run_id)
            slot.run_goals_from = slot.memory.goal_index + 1
        path.unlink(missing_ok=True)
        logger.warning("memory of %s dropped: %s", slot.key, reason)

    def save(self, slot: HomeSlot) -> None:
        path = self.path(slot.key)
        try:
            with slot.lock:
                data = memory_bytes(slot.memory, slot.anchor_world, slot.robot_frame, slot.dropped)
            self.dir.mkdir(parents=True, exist_ok=True)
            tmp = path.with_name(f".{slot.key}.tmp")
            tmp.write_bytes(data)
            tmp.replace(path)
            logger.info(
                "memory of %s saved to %s (%d keyframes, %d bytes)", slot.key, path, len(slot.memory), len(data)
            )
        except Exception:
            logger.exception("saving the memory of %s to %s failed", slot.key, path)

    def forget(self, key: str) -> bool:
        """Forget a home: its memory emptied and its file removed. ``MemoryInUse`` while a run uses
        it. True if there was something to forget."""
        path = self.path(key)
        with self._lock:
            slot = self._slots.get(key)
            if slot is not None and slot.in_use:
                raise MemoryInUse(f"a run in {key} is using its memory: stop it first")
            had = path.is_file() or (slot is not None and (len(slot.memory) > 0 or slot.memory.goals != []))
            self._slots.pop(key, None)
            path.unlink(missing_ok=True)
        logger.info("memory of %s forgotten", key)
        return had

    def summary(self, key: str) -> dict[str, Any]:
        """What the home's memory holds, as plain JSON: ``HomeMemory.summary`` (each goal with the
        run that asked for it, ``HomeSlot.run_of``), the home, and its ``known_objects``."""
        slot = self.slot(key)
        for _ in range(5):  # the run's worker may change the memory while it is read
            try:
                s = slot.memory.summary()
                break
            except RuntimeError:
                time.sleep(0.01)
        else:
            s = slot.memory.summary()
        goals = {g.goal_index: g for g in slot.memory.goals}  # read after: it holds every goal of ``s``
        for out in s["goals"]:
            out["run_id"] = slot.run_of(goals[out["goal_index"]])
        dropped = slot.dropped
        return {
            "home": key,
            "in_use": slot.in_use,
            "saved": self.path(key).is_file(),
            **s,
            "objects": known_objects(s["goals"]),
            "dropped": None if dropped is None else dropped.to_json(),
        }

    def remembers(self, key: str, run_id: str) -> bool:
        """Whether the home's memory holds a request asked for by this console run."""
        return any(g.run_id == run_id for g in self.slot(key).memory.goals)

    def map_png(self, key: str, size_px: int = 480) -> bytes:
        """The remembered map with the known objects (final candidates of the goals, not rejected),
        each numbered with its request, and the last pose, as a PNG; an empty picture when nothing
        is remembered."""
        from PIL import Image

        from console.pictures import render_map

        slot = self.slot(key)
        memory = slot.memory
        snapshot = memory.grid.snapshot() if memory.grid is not None else None
        marks: list[tuple[tuple[float, float], list[str]]] = []  # a place and the requests that found it
        for g in memory.goals:
            for c in g.candidates:
                if c.state != "rejected":
                    near = next((m for m in marks if math.dist(m[0], c.xy_m) < MARK_MERGE_M), None)
                    if near is None:
                        marks.append(((c.xy_m[0], c.xy_m[1]), [str(g.goal_index + 1)]))
                    elif str(g.goal_index + 1) not in near[1]:
                        near[1].append(str(g.goal_index + 1))
        rgb, _ = render_map(
            snapshot,
            pose=memory.last_pose,
            extra_points_xy_m=np.asarray([xy for xy, _ in marks], np.float64).reshape(-1, 2),
            extra_labels=[",".join(requests) for _, requests in marks],  # the request numbers, as the list says
            size_px=size_px,
        )
        buf = io.BytesIO()
        Image.fromarray(rgb).save(buf, format="PNG")
        return buf.getvalue()
