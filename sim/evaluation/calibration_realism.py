"""Calibration pairs as the agent sees them under a realism profile (``imgnav calibrate --realism``, issue 30).

Under the ``stretch`` profile the agent compares a phone-like photo of the goal
(``sim.realism.phone_photo``: exposure, white balance, gamma, blur, a 4:3 crop, JPEG) against
robot camera frames as the bridge delivers them (``sim.realism.noisy_rgb``: exposure and
white-balance drift, sensor noise, JPEG). A calibration pair (i, j), i < j, is then scored as
the *goal version* of image i against the *frame version* of image j, in the order the agent
matches them (goal first), each version's features extracted once with the agent's keypoint
budget for its role (``goal_max_keypoints``, ``obs_max_keypoints``).

Each image's processing is deterministic: a ``RealismRun`` keyed by the image's name in the
cache (``calibration/<name>``) and the realism seed, as an evaluation run is keyed by its
episode id, so the same image gets the same processing in every run and in both of its roles'
pairs. The goal version draws from that run's ``goal_photo`` stream, the frame version from its
``rgb`` stream after ``DRIFT_FRAMES`` frames of exposure and white-balance drift (a frame from
within an episode, where the drift has forgotten its start, not an episode's first frame).

Only colour is modelled: the frame version keeps the goal image's geometry (the robot camera's
own field of view and resolution are not applied), as the calibration pairs are goal views.

Without a colour component (the ``clean`` profile, or ``--realism-only`` without ``rgb`` and
``goal_photo``) the pairs are scored exactly as without a profile: one feature set per image
with the goal's keypoint budget, each pair (i, j) as image i against image j.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np

from agent.reid.base import Features, Matcher
from sim.evaluation.calibration_core import score_pairs
from sim.realism import Realism

# Frames of colour drift before a calibration frame: the walk's unbounded spread after them
# (0.02 * sqrt(100) = 0.2 in log gain, 0.08 in log white balance) is well beyond its bounds
# (0.1, 0.05), so the frame's exposure and white balance are those of any frame within a run.
DRIFT_FRAMES = 100


def photometric(realism: Realism | None) -> bool:
    """Whether the profile changes what the matcher sees (a goal photo or the bridge's colour)."""
    return realism is not None and (realism.profile.goal_photo is not None or realism.profile.rgb is not None)


def image_key(name: str) -> str:
    """The key of an image's noise (its name in the image cache), as an episode id keys a run's."""
    return f"calibration/{name}"


def goal_version(image: np.ndarray, realism: Realism | None, name: str) -> np.ndarray:
    """Image ``name`` as the goal photo the agent is given (the image itself without a goal photo)."""
    run = realism.start(image_key(name)) if realism is not None else None
    return image if run is None else run.goal_photo(image)


def frame_version(image: np.ndarray, realism: Realism | None, name: str) -> np.ndarray:
    """Image ``name`` as a robot camera frame from within a run (the image itself without ``rgb``)."""
    run = realism.start(image_key(name)) if realism is not None else None
    if run is None or run.profile.rgb is None:
        return image
    run.skip_frames(DRIFT_FRAMES)
    return run.rgb(image)


def role_features(
    matcher: Matcher,
    images: Iterable[np.ndarray],
    names: Sequence[str],
    realism: Realism | None,
    goal_max_keypoints: int,
    obs_max_keypoints: int,
) -> tuple[list[Features], list[Features] | None]:
    """(goal features, frame features) per image; frame features None when both roles see the
    image itself (one feature set, with the goal's keypoint budget, as the clean calibration)."""
    goal: list[Features] = []
    frame: list[Features] | None = [] if photometric(realism) else None
    for image, name in zip(images, names, strict=True):
        if frame is None:
            goal.append(matcher.extract(image, goal_max_keypoints))
            continue
        goal.append(matcher.extract(goal_version(image, realism, name), goal_max_keypoints))
        frame.append(matcher.extract(frame_version(image, realism, name), obs_max_keypoints))
    return goal, frame


def score_calibration_pairs(
    matcher: Matcher,
    goal_features: Sequence[Features],
    frame_features: Sequence[Features] | None,
    pairs: np.ndarray,
    progress: Iterable | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(conf, count) per pair (i, j): the goal version of i against the frame version of j."""
    return score_pairs(matcher, goal_features, pairs, progress, features_obs=frame_features)
