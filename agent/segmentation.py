"""Masks of the goal instance in the goal image (docs/architecture.md section 2.3).

Sources:

* ``crop``: the paper's "Crop-Projected" ablation: the central third in width, from one
  third of the height down to 7/8 (Krantz et al. 2023, Table 2).
* ``grabcut``: a class-agnostic segmentation of the central object that needs no weights:
  OpenCV GrabCut initialised with a central rectangle and a definite-foreground seed at the
  image centre (goal images are framed on the instance), keeping the connected component
  at (or nearest to) the centre. Falls back to ``crop`` when it returns (almost) nothing.
* ``oracle``: an injected callable (the evaluation supplies the simulator's ground truth;
  the agent never imports sim/).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np

log = logging.getLogger(__name__)

MaskSource = Literal["crop", "grabcut", "oracle"]
GoalMaskFn = Callable[[np.ndarray], np.ndarray]  # goal image (h, w, 3) uint8 -> (h, w) bool


@dataclass(frozen=True, slots=True)
class SegmentationConfig:
    source: MaskSource = "grabcut"
    grabcut_max_side_px: int = 256  # GrabCut runs once per run; 256 px takes ~0.1-0.3 s
    grabcut_iterations: int = 5
    grabcut_rect: tuple[float, float, float, float] = (0.1, 0.1, 0.9, 0.95)  # x0, y0, x1, y1 (fractions)
    grabcut_seed_radius: float = 0.04  # definite foreground disk at the centre, fraction of the short side
    min_mask_fraction: float = 0.01  # below this the segmentation failed -> crop


def crop_mask(height_px: int, width_px: int) -> np.ndarray:
    """(h, w) bool: x in [w/3, 2w/3), y in [h/3, 7h/8)."""
    m = np.zeros((height_px, width_px), bool)
    m[height_px // 3 : (7 * height_px) // 8, width_px // 3 : (2 * width_px) // 3] = True
    return m


def grabcut_mask(rgb: np.ndarray, config: SegmentationConfig = SegmentationConfig()) -> np.ndarray:
    h, w = rgb.shape[:2]
    s = min(1.0, config.grabcut_max_side_px / max(h, w))
    small = cv2.resize(rgb, (max(8, int(w * s)), max(8, int(h * s))), interpolation=cv2.INTER_AREA) if s < 1 else rgb
    sh, sw = small.shape[:2]
    x0, y0, x1, y1 = config.grabcut_rect
    init = np.full((sh, sw), cv2.GC_BGD, np.uint8)
    init[int(y0 * sh) : int(y1 * sh), int(x0 * sw) : int(x1 * sw)] = cv2.GC_PR_FGD
    r = max(1, int(config.grabcut_seed_radius * min(sh, sw)))
    cv2.circle(init, (sw // 2, sh // 2), r, int(cv2.GC_FGD), -1)
    bgd, fgd = np.zeros((1, 65), np.float64), np.zeros((1, 65), np.float64)
    bgr = cv2.cvtColor(np.ascontiguousarray(small), cv2.COLOR_RGB2BGR)
    # no rectangle: the mask initialises it (OpenCV's stubs do not allow the None it takes then)
    cv2.grabCut(bgr, init, None, bgd, fgd, config.grabcut_iterations, cv2.GC_INIT_WITH_MASK)  # type: ignore[call-overload]
    fg = ((init == cv2.GC_FGD) | (init == cv2.GC_PR_FGD)).astype(np.uint8)
    n, labels = cv2.connectedComponents(fg, connectivity=8)
    if n > 2:  # keep the component at the centre (the seed makes it exist)
        keep = labels[sh // 2, sw // 2]
        if keep == 0:
            sizes = np.bincount(labels.ravel())
            sizes[0] = 0
            keep = int(np.argmax(sizes))
        fg = (labels == keep).astype(np.uint8)
    mask = cv2.resize(fg, (w, h), interpolation=cv2.INTER_NEAREST).astype(bool) if s < 1 else fg.astype(bool)
    return mask


class GoalSegmenter:
    def __init__(self, config: SegmentationConfig = SegmentationConfig(), oracle: GoalMaskFn | None = None) -> None:
        if config.source == "oracle" and oracle is None:
            raise ValueError("segmentation source 'oracle' needs an injected goal-mask callable")
        self.config = config
        self.oracle = oracle

    def mask(self, goal_rgb: np.ndarray) -> np.ndarray:
        """(h, w) bool mask of the goal instance in ``goal_rgb``."""
        h, w = goal_rgb.shape[:2]
        src = self.config.source
        if src == "crop":
            return crop_mask(h, w)
        if src == "oracle":
            assert self.oracle is not None
            m = np.asarray(self.oracle(goal_rgb), bool)
            if m.shape != (h, w):
                raise ValueError(f"oracle goal mask {m.shape} does not match the goal image {(h, w)}")
            return m
        m = grabcut_mask(goal_rgb, self.config)
        if m.mean() < self.config.min_mask_fraction:
            log.info("GrabCut found no central object (%.3f of the image); using the central crop", m.mean())
            return crop_mask(h, w)
        return m
