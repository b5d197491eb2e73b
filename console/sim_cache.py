"""What the console keeps between simulator runs: the last home built, and what is computed
from that home alone and would be computed again, identically, by the next run there.

* ``WorldCache``: the last ``SimWorld`` built (keys ``("home", seed, n_rooms)`` and
  ``("episode", seed)``); building a home is most of the time from upload to the first action.
* Derived data of that world (``WorldCache.derived``), kept only while the world is: the
  scene is static (the robot is no body in it), so for one world these are pure functions of
  their key:
  - ``scoring``: a known target's viewpoints and geodesic field from a start's component
    (``sim.backend.GoalScoring``, ray tests and fast marching, ~0.2 s), keyed by the target
    instance and a digest of the component;
  - ``start_render``: the first frame at a start pose (pose and camera in the key; ~0.1 s of
    TinyRenderer). Every run gets its own copy of the arrays.

Each kind is bounded (least recently used dropped): a custom start per run must not grow it.
Kept arrays are read-only, so that no run can change what the next one reads.
"""

from __future__ import annotations

import hashlib
import logging
import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable
from typing import Any

import numpy as np

logger = logging.getLogger(__name__)

# entries kept per kind: a start frame is ~3 MB (640 x 480 RGB, depth, segmentation),
# a scoring field ~0.5 MB; a home offers a handful of starts and ~10 goal instances
DERIVED_LIMITS = {"scoring": 32, "start_render": 8}


class WorldCache:
    """The last simulator home built, kept for the next run (the console runs one at a time),
    with data derived from it. Used by one thread at a time: the run's worker, or the warm-up
    before any run."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._key: tuple | None = None
        self._world: Any = None
        self._derived: dict[str, OrderedDict[Hashable, Any]] = {}

    @property
    def key(self) -> tuple | None:
        with self._lock:
            return self._key

    def get(self, key: tuple, build: Callable[[], Any]) -> Any:
        with self._lock:
            if self._key != key:
                if self._world is not None:
                    self._world.close()
                    self._world, self._key = None, None
                self._derived.clear()  # computed from the world just closed
                self._world = build()
                self._key = key
            return self._world

    def warm(self, key: tuple, build: Callable[[], Any]) -> bool:
        """Build ``key``'s world only if none is kept: never replaces a world a run may be using."""
        with self._lock:
            if self._world is not None:
                return False
            self._derived.clear()
            self._world = build()
            self._key = key
            return True

    def derived(self, key: tuple, kind: str, item: Hashable, build: Callable[[], Any]) -> Any:
        """``build()`` for ``item`` of world ``key``, kept while that world is the one kept.
        When ``key`` is not the kept world (it was replaced), the value is built and not kept."""
        limit = DERIVED_LIMITS[kind]
        with self._lock:
            if self._world is None or self._key != key:
                logger.debug("%s for %s: world %s is not the one kept; not cached", kind, key, self._key)
                return build()
            table = self._derived.setdefault(kind, OrderedDict())
            if item in table:
                table.move_to_end(item)
                return table[item]
            value = build()
            table[item] = value
            while len(table) > limit:
                table.popitem(last=False)
            return value

    def derived_items(self, kind: str) -> list[Hashable]:
        """The items of ``kind`` kept now, oldest first (for tests and logs)."""
        with self._lock:
            return list(self._derived.get(kind, ()))

    def close(self) -> None:
        with self._lock:
            if self._world is not None:
                self._world.close()
            self._world, self._key = None, None
            self._derived.clear()


def _read_only(*arrays: np.ndarray | None) -> None:
    for a in arrays:
        if a is not None:
            a.setflags(write=False)


def kept_scoring(
    worlds: WorldCache, key: tuple, world: Any, goal_instance_id: int, start_pose_world: Any
) -> Callable[[], Any]:
    """A ``SimBackend`` ``scoring`` callable: the target's ``GoalScoring`` from the start's
    component, computed once per world, target and component. Starts in the same component
    share it (the viewpoints depend on the start only through its component)."""
    from sim.backend import goal_scoring, start_component

    def scoring() -> Any:
        free = start_component(world, start_pose_world)
        digest = hashlib.blake2b(np.packbits(free).tobytes(), digest_size=16).hexdigest()

        def build() -> Any:
            value = goal_scoring(world, goal_instance_id, free)
            _read_only(value.viewpoints_world, value.field)
            return value

        return worlds.derived(key, "scoring", (int(goal_instance_id), free.shape, digest), build)

    return scoring


def kept_start_render(
    worlds: WorldCache, key: tuple, world: Any, start_pose_world: Any, camera: Any
) -> Callable[[], Any]:
    """A ``SimBackend`` ``start_render`` callable: the frame at the start pose, rendered once
    per world, pose and camera; each call returns a ``Render`` with arrays of its own."""
    from sim.camera import Render

    def build() -> Any:
        r = world.render(start_pose_world, camera)
        _read_only(r.rgb, r.depth_m, r.seg_raw)
        return r

    def start_render() -> Any:
        kept = worlds.derived(key, "start_render", (start_pose_world, camera), build)
        return Render(kept.rgb.copy(), kept.depth_m.copy(), np.array(kept.seg_raw, copy=True), kept.seg_lut)

    return start_render
