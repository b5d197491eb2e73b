"""OpenCV SIFT with Lowe's ratio test: the non-learned baseline matcher.

SIFT has no learned match confidence; for the ``conf`` score each match gets
``1 - d1/d2`` (its margin in the ratio test, 0 at the threshold's limit of 1).
"""

from __future__ import annotations

import cv2
import numpy as np

from agent.reid.base import Features, Matches, resize_max_side


class SiftRatio:
    name = "sift"

    def __init__(self, max_side_px: int = 640, ratio: float = 0.8) -> None:
        self.max_side_px = max_side_px
        self.ratio = ratio
        self._bf = cv2.BFMatcher(cv2.NORM_L2)

    def extract(self, rgb: np.ndarray, max_keypoints: int) -> Features:
        img, scale = resize_max_side(rgb, self.max_side_px)
        gray = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
        sift = cv2.SIFT_create(nfeatures=max_keypoints)  # type: ignore[attr-defined]  # missing from OpenCV's stubs
        kps, desc = sift.detectAndCompute(gray, None)
        xy = np.array([k.pt for k in kps], np.float32).reshape(-1, 2) * scale
        if desc is None:
            desc = np.zeros((0, 128), np.float32)
        return Features(xy.astype(np.float32), desc.astype(np.float32), (rgb.shape[1], rgb.shape[0]))

    def match(self, goal: Features, obs: Features) -> Matches:
        if len(goal) < 1 or len(obs) < 2:
            return Matches.empty()
        knn = self._bf.knnMatch(goal.descriptors, obs.descriptors, k=2)
        i0, i1, conf = [], [], []
        for pair in knn:
            if len(pair) < 2:
                continue
            a, b = pair
            if b.distance > 0 and a.distance < self.ratio * b.distance:
                i0.append(a.queryIdx)
                i1.append(a.trainIdx)
                conf.append(1.0 - a.distance / b.distance)
        return Matches(np.asarray(i0, np.int64), np.asarray(i1, np.int64), np.asarray(conf, np.float32))
