"""A cheap first stage for re-identification: run the learned matcher only where it could fire.

LighterGlue costs about three times the keypoint extraction per frame, and the goal is absent
from almost every frame of an episode. The gate scores a frame with what the extraction already
gave: mutual nearest neighbours of the L2-normalised descriptors (goal descriptors once per run,
one matrix product per frame) whose cosine similarity reaches ``min_cosine``. Its score is the
number of such pairs. LighterGlue keeps a match only where the descriptors of both keypoints
agree (its confidence is a function of their similarity and of their context), so a frame with
few mutually-nearest, similar descriptor pairs rarely reaches tau. How rarely is measured:
``imgnav calibrate --gate`` picks the threshold so that at most 1% of the frames (train goal-image
pairs and train-episode frames) that the full matcher scores at or above tau fall below it.

Below the threshold the frame's re-ID score is 0 and LighterGlue does not run.

The second stage (the exit stage, ``reid.gate_exit_layer``): a frame past the first stage runs
LighterGlue's first layers (two by default), whose assignment head (trained for every layer, deep
supervision) scores it; below the exit threshold it stops there and scores 0, and otherwise it
runs on to the last layer unchanged. On 3,696 train-episode frames (18 episodes), descriptor-level
gates of every kind tried (a higher cosine, a ratio test, homography or fundamental-matrix inliers
of the MNN pairs, sums of similarity) passed at best 55% of the searching frames with at most 1% of
the frames >= tau/2 dropped (this count: 61%); on 4,051 (20 episodes) the head after layer 2 passed
6% and dropped none: what decides a match is context, which only the matcher's own layers see.
LighterGlue's first layers see every keypoint (it prunes only later), so the stage runs on each
side's best ``reid.gate_exit_keypoints`` (384) keypoints, a quarter of the cost; a frame past it is
matched in full from the start (docs/experiments/exit-stage-keypoints.md). ``imgnav calibrate
--gate`` calibrates its threshold like the first stage's (``gate_threshold_for`` on the same two
train sources), for the layer and the number of keypoints it is run with.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

# XFeat's own mutual-nearest-neighbour matcher keeps pairs above this cosine similarity
# (Potje et al., CVPR 2024; ``XFeat.match(min_cossim=0.82)``).
DEFAULT_MIN_COSINE = 0.82


def normalise_rows(desc: Any) -> torch.Tensor:
    """(N, D) float32 rows scaled to unit length (zero rows stay zero), as a torch tensor.

    Torch, not numpy: its intra-op threads are the ones the agent sets (one per evaluation
    worker), where numpy's BLAS would start its own threads per process and oversubscribe."""
    t = desc.detach() if isinstance(desc, torch.Tensor) else torch.from_numpy(np.ascontiguousarray(desc))
    t = t.to(torch.float32)
    t = t.reshape(len(t), -1) if t.numel() else t.reshape(0, t.shape[-1] if t.ndim > 1 else 0)
    return t / t.norm(dim=1, keepdim=True).clamp_min(1e-12)


class MNNGate:
    """Mutual-nearest-neighbour count between the goal's and a frame's descriptors.

    ``set_goal`` once per run (keeps the goal's normalised descriptors, transposed for the
    product); ``score(obs_descriptors)`` per frame.
    """

    def __init__(self, min_cosine: float = DEFAULT_MIN_COSINE) -> None:
        self.min_cosine = float(min_cosine)
        self._goal_t: torch.Tensor | None = None  # (D, N_goal) float32

    def set_goal(self, goal_descriptors: Any) -> None:
        self._goal_t = normalise_rows(goal_descriptors).T.contiguous()

    @torch.inference_mode()
    def score(self, obs_descriptors: Any) -> float:
        if self._goal_t is None:
            raise RuntimeError("MNNGate.set_goal() first")
        obs = normalise_rows(obs_descriptors)
        if len(obs) == 0 or self._goal_t.shape[1] == 0:
            return 0.0
        return float(mnn_count(obs @ self._goal_t, self.min_cosine))


@torch.inference_mode()
def mnn_count(sim_obs_goal: Any, min_cosine: float) -> int:
    """Pairs (i, j) where j is i's most similar goal row, i is j's most similar frame row, and
    their similarity reaches ``min_cosine``. sim_obs_goal: (N_obs, N_goal) cosine similarities
    (a torch tensor or a numpy array)."""
    sim = sim_obs_goal if isinstance(sim_obs_goal, torch.Tensor) else torch.from_numpy(np.asarray(sim_obs_goal))
    if sim.numel() == 0:
        return 0
    best_val, best_goal = sim.max(dim=1)  # (N_obs,)
    best_obs = sim.argmax(dim=0)  # (N_goal,)
    rows = torch.arange(sim.shape[0])
    mutual = best_obs[best_goal] == rows
    return int((mutual & (best_val >= min_cosine)).sum())


def gate_threshold_for(
    full_scores: np.ndarray, gate_scores: np.ndarray, tau: float, max_drop: float = 0.01, near_tau: float = 0.5
) -> tuple[float, dict[str, float]]:
    """The gate threshold for one source of frames: at most ``max_drop`` of the frames the full
    matcher scores at or above ``tau`` may fall below it (a frame is dropped when its gate score
    is below the threshold).

    Two estimates, the smaller one wins:

    * direct: the largest threshold that drops at most ``max_drop`` of the positives. With few
      positives (fewer than ``3 / max_drop``) it is decided by the lowest one or two of them and
      says little about the next frame;
    * bound: the gate score as a share of the full score, at its ``max_drop`` quantile over the
      frames scoring at least ``near_tau * tau`` (more frames than the positives alone, and the
      ratio is lowest at modest full scores), times tau: what a frame that just reaches tau can
      be expected to score at least.

    The bound is rounded down to a whole score: exact for the first stage's counts, a little
    conservative for the exit stage's sums of confidences.

    Returns the threshold and the figures behind it: both estimates, the positives, the share
    of positives dropped, and the share of all frames the gate lets through (what the full
    matcher still costs).
    """
    full = np.asarray(full_scores, np.float64)
    gate = np.asarray(gate_scores, np.float64)
    if full.shape != gate.shape or full.ndim != 1:
        raise ValueError("full_scores and gate_scores must be 1-D arrays of the same length")
    pos = gate[full >= tau]
    if len(pos) == 0:
        raise ValueError(f"no frame reaches tau={tau:.3g}: cannot calibrate the gate")
    allowed = int(np.floor(max_drop * len(pos)))  # positives that may fall below the threshold
    # Gate scores are counts: a threshold t drops the positives with score < t. Taking the
    # (allowed+1)-th smallest score as t drops at most `allowed` of them (ties stay above).
    direct = float(np.sort(pos)[allowed])
    near = full >= near_tau * tau
    ratio = gate[near] / full[near]
    bound = float(np.floor(np.quantile(ratio, max_drop, method="lower") * tau))
    threshold = min(direct, bound)
    return threshold, {
        "positives": float(len(pos)),
        "direct": direct,
        "bound": bound,
        "near_tau_frames": float(near.sum()),
        "dropped_share": float(np.mean(pos < threshold)),
        "pass_share": float(np.mean(gate >= threshold)),
        "frames": float(len(full)),
    }
