"""The frames kept for a second look when exploration is exhausted (``policy.exhausted_recheck_frames``).

While searching, most frames never reach the full matcher (the gate drops them) or score below the
potential threshold. When the whole home has been explored and nothing scored, the goal was still
most likely in some of those frames: seen from a side the goal photo does not show, or too far or
too small to match well. Their rank comes from a cheap score every frame has: the gate's count of
mutually-nearest descriptor pairs with the goal image (on a val toilet the matcher never scored above
tau/2, the 14 frames with the most pairs were all frames of the goal).

``FrameShortlist`` keeps the best ``capacity`` observations by that score, one per pose (the robot's
rescans turn on the spot and see the same frames again), with copies of their images: a backend may
reuse its buffers.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import replace

import numpy as np

from agent.types import Observation


class FrameShortlist:
    def __init__(self, capacity: int) -> None:
        if capacity < 0:
            raise ValueError(f"capacity {capacity} must be >= 0")
        self.capacity = int(capacity)
        self._heap: list[tuple[float, int, Observation]] = []  # min-heap on the rank
        self._poses: dict[tuple[int, int, int], int] = {}  # pose key -> step kept there

    def __len__(self) -> int:
        return len(self._heap)

    @staticmethod
    def _key(obs: Observation) -> tuple[int, int, int]:
        p = obs.pose
        return (round(p.x_m / 0.05), round(p.y_m / 0.05), round(math.degrees(p.yaw_rad) / 5.0) % 72)

    def offer(self, obs: Observation, rank: float) -> bool:
        """Keep ``obs`` if it ranks among the best ``capacity`` frames and no frame from the same
        pose is kept (the better of the two stays). Returns whether it was kept."""
        if self.capacity == 0 or not math.isfinite(rank):
            return False
        key = self._key(obs)
        if len(self._heap) >= self.capacity and rank <= self._heap[0][0]:
            return False
        if key in self._poses:
            same = next(i for i, e in enumerate(self._heap) if e[1] == self._poses[key])
            if self._heap[same][0] >= rank:
                return False
            self._heap.pop(same)
            heapq.heapify(self._heap)
        kept = replace(obs, rgb=np.array(obs.rgb, copy=True), depth_m=np.array(obs.depth_m, copy=True))
        heapq.heappush(self._heap, (float(rank), int(obs.step), kept))
        self._poses[key] = int(obs.step)
        if len(self._heap) > self.capacity:
            _, step, dropped = heapq.heappop(self._heap)
            if self._poses.get(self._key(dropped)) == step:
                del self._poses[self._key(dropped)]
        return True

    def take(self) -> list[tuple[float, Observation]]:
        """The kept frames, best first, and forget them."""
        out = [(r, o) for r, _, o in sorted(self._heap, key=lambda e: (-e[0], e[1]))]
        self._heap, self._poses = [], {}
        return out
