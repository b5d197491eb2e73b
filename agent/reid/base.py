"""Keypoint re-identification: shared data types, the matcher protocol and the score functions.

The paper's classifier (Krantz et al. 2023, section 3.2) says the goal instance is in view
when ``score >= tau``, with ``score`` the sum of the matcher's confidences over the matches
("Keypoint-Conf", ``conf``) or the number of matches ("Keypoint-Match", ``count``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Literal, Protocol

import cv2
import numpy as np

ScoreKind = Literal["conf", "count"]


@dataclass(frozen=True, slots=True, eq=False)
class Features:
    """Keypoints of one image.

    keypoints_xy: (N, 2) float32 pixel (x, y) in the *original* image.
    descriptors:  matcher-specific (a torch tensor or a numpy array), N rows.
    image_size_wh: (width, height) of the original image.
    extra: matcher-specific payload (e.g. the resized keypoints a learned matcher needs).
    """

    keypoints_xy: np.ndarray
    descriptors: Any
    image_size_wh: tuple[int, int]
    extra: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return int(len(self.keypoints_xy))


@dataclass(frozen=True, slots=True, eq=False)
class Matches:
    """Matches between the goal image (0) and an egocentric image (1).

    idx_goal, idx_obs: (M,) int64 keypoint indices; confidence: (M,) float32 in [0, 1].
    """

    idx_goal: np.ndarray
    idx_obs: np.ndarray
    confidence: np.ndarray

    @staticmethod
    def empty() -> Matches:
        return Matches(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.float32))

    def __len__(self) -> int:
        return int(len(self.idx_goal))


class Matcher(Protocol):
    """A feature extractor plus a matcher. ``extract`` is called once for the goal image and
    once per egocentric frame; ``match`` pairs them."""

    name: str

    def extract(self, rgb: np.ndarray, max_keypoints: int) -> Features: ...

    def match(self, goal: Features, obs: Features) -> Matches: ...


def score(matches: Matches, kind: ScoreKind) -> float:
    """``conf``: sum of match confidences (Keypoint-Conf); ``count``: number of matches (Keypoint-Match)."""
    if kind == "conf":
        return float(np.sum(matches.confidence, dtype=np.float64))
    if kind == "count":
        return float(len(matches))
    raise ValueError(f"unknown score kind {kind!r}")


def valid_matches(matches0: np.ndarray, scores0: np.ndarray, min_confidence: float, n_obs: int) -> Matches:
    """Matches from a LightGlue-style output (one row of ``matches0``/``matching_scores0``).

    A match is valid when it has a partner (index >= 0, < n_obs) *and* its confidence
    reaches ``min_confidence``. Both tests are applied with ``&`` into a fresh array (the
    reference code called numpy's three-argument ``logical_and``, whose third argument is
    the *output*, and so lost one of the tests).
    """
    m0 = np.asarray(matches0, np.int64).reshape(-1)
    s0 = np.asarray(scores0, np.float32).reshape(-1)
    valid = (m0 >= 0) & (m0 < n_obs) & (s0 >= min_confidence)
    idx = np.flatnonzero(valid)
    return Matches(idx.astype(np.int64), m0[idx], s0[idx])


def resize_max_side(rgb: np.ndarray, max_side_px: int) -> tuple[np.ndarray, float]:
    """Downscale (never upscale) so that the longer side is at most ``max_side_px``.

    Returns the image and the factor original/resized (multiply resized pixel coordinates by it).
    """
    h, w = rgb.shape[:2]
    s = max(h, w) / float(max_side_px) if max_side_px > 0 else 1.0
    if s <= 1.0:
        return rgb, 1.0
    nw, nh = max(1, int(round(w / s))), max(1, int(round(h / s)))
    out = cv2.resize(rgb, (nw, nh), interpolation=cv2.INTER_AREA)
    return out, math.sqrt((w / nw) * (h / nh))
