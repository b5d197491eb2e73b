"""Images for the re-identification tests: a goal photo and views of it with a known warp."""

from __future__ import annotations

import cv2
import numpy as np
import skimage.data


def goal_and_views():
    """(goal 512 x 512, a 360 x 640 view of it (rotated, scaled, cropped), an unrelated 360 x 640
    image, and the goal -> view pixel map)."""
    goal = cv2.resize(skimage.data.astronaut(), (512, 512))
    A = cv2.getRotationMatrix2D((256, 256), 10, 0.8)  # 2x3: goal -> warped
    warped = cv2.warpAffine(goal, A, (512, 512))
    x0, y0, x1, y1 = 100, 60, 330, 460
    sx, sy = 360 / (x1 - x0), 640 / (y1 - y0)
    same = cv2.resize(warped[y0:y1, x0:x1], (360, 640))

    # goal pixel -> view pixel
    def to_view(xy):
        w = xy @ A[:, :2].T + A[:, 2]
        return np.stack([(w[:, 0] - x0) * sx, (w[:, 1] - y0) * sy], axis=1)

    other = cv2.resize(skimage.data.coffee(), (360, 640))
    return goal, same, other, to_view
