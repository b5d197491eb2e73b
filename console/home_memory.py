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

**On disk.** ``<data>/memory/<home>.npz``, written when a run in the home ends (atomically:
a temporary file, then a rename), read lazily the first time the home is asked for. No pickle:
the arrays are the archive's members (read with ``allow_pickle=False``) and everything else is
one JSON member (``meta``) whose tree names its arrays. A file that cannot be read, or that was
written for another format, mapping or matcher, is logged as an error, moved aside
(``<home>.unreadable-<time>.npz``, never deleted) and the home starts with an empty memory.
Format 2 gives each goal the id of the console run that asked for it (``GoalSummary.run_id``);
a format 1 file (written before) is read with no run ids. A later format is refused like any
other unreadable file.

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
import json
import logging
import math
import re
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from agent.types import CandidateInfo, Pose2D
from console.artifacts import valid_run_id

if TYPE_CHECKING:  # agent.memory imports torch: not before console.agents.passive_openmp_wait
    from agent.mapping import MappingConfig
    from agent.memory import GoalSummary, HomeMemory, MemoryConfig

logger = logging.getLogger(__name__)

FORMAT_VERSION = 2
READABLE_FORMATS = (1, 2)  # 1: the goals have no run ids
MARK_MERGE_M = 0.5  # known objects closer than this are one mark on the map, numbered with each request
HOME_KEY = re.compile(r"^((home|scene)-\d{1,9}|robot-[0-9a-f]{10})$")


class MemoryInUse(RuntimeError):
    """The home's memory is being used by the active run (HTTP 409 to forget it)."""


class MemoryFileError(ValueError):
    """A memory file that cannot be read back (its reason says why)."""


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


@dataclass(frozen=True, slots=True)
class RobotFrame:
    """Where the last run in a robot home left the base, in the robot's map frame, and the
    bridge's step count then (``console.robot_memory`` compares the next run's start with it).

    end_map: the base pose the robot last reported (or the goal of a move still under way).
    last_step: the highest step the robot had echoed (None: it did not say).
    run_id: the console run that left it there.
    """

    end_map: Pose2D
    last_step: int | None
    run_id: str | None

    def to_json(self) -> dict[str, Any]:
        return {"end_map": _pose(self.end_map), "last_step": self.last_step, "run_id": self.run_id}

    @staticmethod
    def from_json(d: Any) -> RobotFrame:
        step = d["last_step"]
        return RobotFrame(_unpose(d["end_map"]), None if step is None else int(step), _run_id_or_none(d["run_id"]))


@dataclass(frozen=True, slots=True)
class DropNote:
    """Why a home's memory was last dropped (not forgotten by the operator), when, and in which run."""

    reason: str
    at_s: float
    run_id: str | None

    def to_json(self) -> dict[str, Any]:
        return {"reason": self.reason, "at_s": self.at_s, "run_id": self.run_id}

    @staticmethod
    def from_json(d: Any) -> DropNote:
        return DropNote(str(d["reason"]), float(d["at_s"]), _run_id_or_none(d["run_id"]))


def _run_id_or_none(value: Any) -> str | None:
    if value is not None and not (isinstance(value, str) and valid_run_id(value)):
        raise MemoryFileError(f"{str(value)[:40]!r} is not a run id")
    return value


# --- the file format ---------------------------------------------------------------------


class _Arrays:
    """The arrays of one file, named ``a0``, ``a1``, ... in the order they are met."""

    def __init__(self) -> None:
        self.arrays: dict[str, np.ndarray] = {}

    def add(self, a: np.ndarray) -> str:
        if a.dtype.kind not in "biufc":
            raise ValueError(f"cannot store an array of dtype {a.dtype}")
        name = f"a{len(self.arrays)}"
        self.arrays[name] = np.ascontiguousarray(a)
        return name


def _encode(value: Any, arrays: _Arrays) -> Any:
    """A matcher payload (packed by ``agent.memory._pack``) as a JSON tree naming its arrays."""
    from agent.memory import _Tensor

    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, (int, float)):
        return value
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, _Tensor):
        return {"tensor": arrays.add(value.array), "dtype": str(value.dtype).removeprefix("torch.")}
    if isinstance(value, np.ndarray):
        return {"array": arrays.add(value)}
    if isinstance(value, dict):
        if not all(isinstance(k, str) for k in value):
            raise ValueError("only string keys can be stored")
        return {"dict": {k: _encode(v, arrays) for k, v in value.items()}}
    if isinstance(value, (list, tuple)):
        return {"tuple" if isinstance(value, tuple) else "list": [_encode(v, arrays) for v in value]}
    raise ValueError(f"cannot store a {type(value).__name__}")


def _decode(node: Any, arrays: Any) -> Any:
    import torch

    from agent.memory import _Tensor

    if node is None or isinstance(node, (bool, str, int, float)):
        return node
    if not isinstance(node, dict) or len(node) not in (1, 2):
        raise MemoryFileError(f"unexpected node {str(node)[:80]}")
    if "tensor" in node:
        dtype = getattr(torch, str(node["dtype"]), None)
        if not isinstance(dtype, torch.dtype):
            raise MemoryFileError(f"unknown tensor dtype {node['dtype']!r}")
        return _Tensor(np.array(arrays[node["tensor"]]), dtype)
    if "array" in node:
        return np.array(arrays[node["array"]])
    if "dict" in node:
        return {str(k): _decode(v, arrays) for k, v in node["dict"].items()}
    if "list" in node:
        return [_decode(v, arrays) for v in node["list"]]
    if "tuple" in node:
        return tuple(_decode(v, arrays) for v in node["tuple"])
    raise MemoryFileError(f"unexpected node {str(node)[:80]}")


def _pose(p: Pose2D) -> list[float]:
    return [p.x_m, p.y_m, p.yaw_rad]


def _unpose(v: Any) -> Pose2D:
    x, y, yaw = (float(t) for t in v)
    return Pose2D(x, y, yaw)


def memory_bytes(
    memory: HomeMemory,
    anchor_world: Pose2D | None,
    robot_frame: RobotFrame | None = None,
    dropped: DropNote | None = None,
) -> bytes:
    """The memory as one ``.npz`` archive (see the module docstring); a robot home's ``robot_frame``
    and ``dropped`` note are written only when there are some."""
    arrays = _Arrays()
    grid = None
    if memory.grid is not None:
        g = memory.grid
        grid = {
            "mapping": dataclasses.asdict(g.config),
            "origin_ij": list(g.origin_ij),
            "layers": {n: arrays.add(getattr(g.layers, n)) for n in g.layers.names()},
        }
    keyframes = [
        {
            "id": kf.id,
            "goal_index": kf.goal_index,
            "step": kf.step,
            "pose": _pose(kf.pose),
            "matcher": kf.matcher,
            "keypoints_xy": arrays.add(kf.keypoints_xy),
            "descriptors": _encode(kf.descriptors, arrays),
            "image_size_wh": list(kf.image_size_wh),
            "points_xyz": arrays.add(kf.points_xyz),
            "extra": _encode(kf.extra, arrays),
        }
        for kf in memory.keyframes
    ]
    meta = {
        "format": FORMAT_VERSION,
        "saved_s": time.time(),
        "anchor_world": None if anchor_world is None else _pose(anchor_world),
        "goal_index": memory.goal_index,
        "matcher": memory.matcher,
        "last_pose": None if memory.last_pose is None else _pose(memory.last_pose),
        "next_id": max((kf.id for kf in memory.keyframes), default=-1) + 1,
        "goals": [dataclasses.asdict(g) for g in memory.goals],
        "grid": grid,
        "keyframes": keyframes,
    }
    if robot_frame is not None:
        meta["robot_frame"] = robot_frame.to_json()
    if dropped is not None:
        meta["dropped"] = dropped.to_json()
    text = json.dumps(meta).encode()
    buf = io.BytesIO()
    np.savez(buf, meta=np.frombuffer(text, np.uint8), **arrays.arrays)  # type: ignore[arg-type]
    return buf.getvalue()


def memory_from_bytes(
    data: bytes, config: MemoryConfig, mapping: MappingConfig, matcher: str
) -> tuple[HomeMemory, Pose2D | None]:
    """A memory and its anchor read back; ``MemoryFileError`` when the bytes are not one written
    by ``memory_bytes`` in a format this version reads (``READABLE_FORMATS``), for this ``mapping``
    config and ``matcher``."""
    file = memory_file_from_bytes(data, config, mapping, matcher)
    return file.memory, file.anchor_world


@dataclass(frozen=True, slots=True, eq=False)
class MemoryFile:
    """What a memory file holds: the memory, its anchor and, for a robot home, the frame record
    and the last drop."""

    memory: HomeMemory
    anchor_world: Pose2D | None
    robot_frame: RobotFrame | None = None
    dropped: DropNote | None = None


def memory_file_from_bytes(data: bytes, config: MemoryConfig, mapping: MappingConfig, matcher: str) -> MemoryFile:
    """``memory_from_bytes`` with the optional members too (``MemoryFile``)."""
    from agent.mapping import LAYER_DTYPES, GridMap, MapLayers
    from agent.memory import HomeMemory, Keyframe

    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as z:
            arrays = {name: z[name] for name in z.files}
        meta = json.loads(arrays.pop("meta").tobytes().decode())
    except MemoryFileError:
        raise
    except Exception as exc:  # zip, npy header, JSON: all say the same thing
        raise MemoryFileError(f"not a memory archive ({type(exc).__name__}: {exc})") from exc
    if not isinstance(meta, dict) or meta.get("format") not in READABLE_FORMATS:
        raise MemoryFileError(
            f"format {meta.get('format') if isinstance(meta, dict) else None!r}, not one of {READABLE_FORMATS}"
        )
    try:
        memory = HomeMemory(config)
        if meta["matcher"] is not None and meta["matcher"] != matcher:
            raise MemoryFileError(f"kept {meta['matcher']} descriptors, the agent uses {matcher}")
        grid_meta = meta["grid"]
        if grid_meta is not None:
            if grid_meta["mapping"] != dataclasses.asdict(mapping):
                raise MemoryFileError("the map was made with another mapping config")
            grid = GridMap(mapping)
            layers = {n: arrays[grid_meta["layers"][n]] for n in grid.layers.names()}
            shapes = {a.shape for a in layers.values()}
            if len(shapes) != 1 or any(a.dtype != LAYER_DTYPES.get(n, bool) or a.ndim != 2 for n, a in layers.items()):
                raise MemoryFileError("the map's layers are not (H, W) arrays of one shape and their types")
            grid.layers = MapLayers(**layers)
            grid.origin_ij = (int(grid_meta["origin_ij"][0]), int(grid_meta["origin_ij"][1]))
            memory.grid = grid
        memory.goal_index = int(meta["goal_index"])
        memory.matcher = meta["matcher"]
        memory.last_pose = None if meta["last_pose"] is None else _unpose(meta["last_pose"])
        memory.goals = [_goal(g) for g in meta["goals"]]
        keyframes = []
        for k in meta["keyframes"]:
            kp = np.asarray(arrays[k["keypoints_xy"]], np.float32)
            pts = np.asarray(arrays[k["points_xyz"]], np.float32)
            if kp.ndim != 2 or kp.shape[1] != 2 or pts.shape != (len(kp), 3):
                raise MemoryFileError(f"keyframe {k['id']}: keypoints {kp.shape} and points {pts.shape} disagree")
            keyframes.append(
                Keyframe(
                    int(k["id"]),
                    int(k["goal_index"]),
                    int(k["step"]),
                    _unpose(k["pose"]),
                    str(k["matcher"]),
                    kp,
                    _decode(k["descriptors"], arrays),
                    (int(k["image_size_wh"][0]), int(k["image_size_wh"][1])),
                    pts,
                    _decode(k["extra"], arrays),
                )
            )
        memory.restore(keyframes, int(meta["next_id"]))
        anchor = None if meta["anchor_world"] is None else _unpose(meta["anchor_world"])
        robot_frame = None if meta.get("robot_frame") is None else RobotFrame.from_json(meta["robot_frame"])
        dropped = None if meta.get("dropped") is None else DropNote.from_json(meta["dropped"])
    except MemoryFileError:
        raise
    except Exception as exc:  # any malformed member or field: the file is not one this module wrote
        raise MemoryFileError(f"malformed memory ({type(exc).__name__}: {exc})") from exc
    return MemoryFile(memory, anchor, robot_frame, dropped)


def _goal(g: dict[str, Any]) -> GoalSummary:
    """A goal's summary as ``memory_bytes`` wrote it (``dataclasses.asdict``); its run id, when
    there is one, must be a run id (it names the run's files in the console's URLs)."""
    from agent.memory import GoalSummary

    run_id = g.get("run_id")
    if run_id is not None and not (isinstance(run_id, str) and valid_run_id(run_id)):
        raise MemoryFileError(f"goal {g.get('goal_index')}: {str(run_id)[:40]!r} is not a run id")
    return GoalSummary(**{**g, "candidates": tuple(CandidateInfo(**c) for c in g["candidates"])})


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
