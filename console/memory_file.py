"""The file of a home's memory (``console.home_memory``): ``memory_bytes`` writes one,
``memory_from_bytes`` / ``memory_file_from_bytes`` read it back.

``<data>/memory/<home>.npz``, written when a run in the home ends (atomically:
a temporary file, then a rename), read lazily the first time the home is asked for. No pickle:
the arrays are the archive's members (read with ``allow_pickle=False``) and everything else is
one JSON member (``meta``) whose tree names its arrays. A file that cannot be read, or that was
written for another format, mapping or matcher, is logged as an error, moved aside
(``<home>.unreadable-<time>.npz``, never deleted) and the home starts with an empty memory.
Format 2 gives each goal the id of the console run that asked for it (``GoalSummary.run_id``);
a format 1 file (written before) is read with no run ids. A later format is refused like any
other unreadable file.

A robot home's file also keeps where the last run left the base (``RobotFrame``) and why the
memory was last dropped (``DropNote``), as optional members of the JSON.
"""

from __future__ import annotations

import dataclasses
import io
import json
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from agent.types import CandidateInfo, Pose2D
from console.artifacts import valid_run_id

if TYPE_CHECKING:  # agent.memory imports torch: not before console.agents.passive_openmp_wait
    from agent.mapping import MappingConfig
    from agent.memory import GoalSummary, HomeMemory, MemoryConfig

FORMAT_VERSION = 2
READABLE_FORMATS = (1, 2)  # 1: the goals have no run ids


class MemoryFileError(ValueError):
    """A memory file that cannot be read back (its reason says why)."""


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
