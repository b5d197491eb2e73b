"""Per-run re-identification: goal features once, egocentric features every step, matched and scored."""

from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Literal

import numpy as np

from agent.reid.base import Features, Matcher, Matches, ScoreKind, score
from agent.reid.gate import MNNGate

log = logging.getLogger(__name__)

_EMPTY_XY = np.zeros((0, 2), np.float32)

MatcherName = Literal["xfeat_lighterglue", "aliked_lightglue", "sift"]


@dataclass(frozen=True, slots=True)
class ReIDConfig:
    matcher: MatcherName = "xfeat_lighterglue"
    score: ScoreKind = "conf"
    # tau: explicit value, else ``calibration_file``, else the packaged
    # agent/calibration/<matcher>_<score>.json written by ``imgnav calibrate``.
    tau: float | None = None
    calibration_file: str | None = None
    goal_max_keypoints: int = 1024
    obs_max_keypoints: int = 1024
    max_side_px: int = 640  # images are downscaled (never upscaled) to this longer side
    min_confidence: float = 0.1  # LightGlue's match filter threshold
    sift_ratio: float = 0.8
    num_threads: int = 2  # torch intra-op threads; 1 per worker when evaluating in parallel
    # The cheap first stage (agent/reid/gate.py): frames whose mutual-nearest-neighbour count
    # is below the gate threshold score 0 without the full matcher (False: the paper's matcher alone).
    gate: bool = True
    gate_shadow: bool = False  # gate off, but compute and record its score (calibration recordings)
    gate_min_cosine: float = 0.82
    # explicit threshold, else ``gate_threshold`` of the calibration file (``imgnav calibrate --gate``)
    gate_threshold: float | None = None
    # The gate's second stage (xfeat_lighterglue): a frame past the first stage is scored by
    # LighterGlue's assignment head after this layer (1-based; 0: off) and stops there, scoring
    # 0, when that score is below the exit threshold; frames that go on get the full matcher's
    # score unchanged. On wherever the gate is on and the calibration file has the threshold.
    gate_exit_layer: int = 2
    # The exit stage sees each side's first (best) K keypoints (0: all of them): a quarter of the
    # cost on 384 (docs/experiments/exit-stage-keypoints.md); a frame past it is matched in full.
    gate_exit_keypoints: int = 384
    # explicit threshold, else ``gate_exit_threshold`` of the calibration file
    gate_exit_threshold: float | None = None


def calibration_path(matcher: str, kind: str) -> Path:
    """The packaged calibration of a matcher and score: ``<matcher>_<kind>.json``."""
    return Path(str(resources.files("agent").joinpath("calibration", f"{matcher}_{kind}.json")))


def _calibration(config: ReIDConfig) -> tuple[Path, dict]:
    path = Path(config.calibration_file) if config.calibration_file else calibration_path(config.matcher, config.score)
    if not path.is_file():
        raise FileNotFoundError(
            f"no re-ID threshold: set reid.tau or run `imgnav calibrate --matcher {config.matcher} "
            f"--score {config.score}` (looked for {path})"
        )
    data = json.loads(path.read_text())
    if data.get("matcher") != config.matcher or data.get("score") != config.score:
        raise ValueError(
            f"{path} calibrates {data.get('matcher')}/{data.get('score')}, not {config.matcher}/{config.score}"
        )
    # LightGlue's adaptive depth was measured and rejected (docs/experiments): every calibration is
    # made with all layers, and a file made with the early stop does not fit this matcher
    if float(data.get("early_stop", -1.0)) != -1.0:
        raise ValueError(
            f"{path} was calibrated with LightGlue's early stop, which this matcher does not use: "
            "calibrate again, or set reid.tau"
        )
    return path, data


def resolve_tau(config: ReIDConfig) -> float:
    """tau from the config or its calibration file (a clear error when neither exists)."""
    if config.tau is not None:
        return float(config.tau)
    return float(_calibration(config)[1]["tau"])


def resolve_gate_threshold(config: ReIDConfig) -> float | None:
    """The gate threshold in force (None: gate off), from the config or the calibration file.

    The gate is calibrated for one tau (it keeps the frames that could reach it). A threshold
    from a calibration file therefore holds only for that file's tau or a higher one; with a
    lower explicit tau, or a file without a gate threshold (an operator's own calibration), the
    gate is switched off with a warning: it must never change what the agent decides.
    """
    if not config.gate:
        return None
    if config.gate_threshold is not None:
        return float(config.gate_threshold)
    path, data = _calibration(config)
    if abs(float(data.get("gate_min_cosine", config.gate_min_cosine)) - config.gate_min_cosine) > 1e-9:
        raise ValueError(
            f"{path}: gate calibrated at min_cosine {data.get('gate_min_cosine')}, "
            f"the config asks for {config.gate_min_cosine}"
        )
    return _threshold_in_file(
        config, path, data, "gate_threshold", "the gate is off, every frame gets the full matcher"
    )


def resolve_exit_threshold(config: ReIDConfig) -> float | None:
    """The exit stage's threshold in force (None: off), from the config or the calibration file.

    Like the first stage's, it holds only for the tau it was calibrated for (or a higher one), at
    the layer it was calibrated at; otherwise the stage is off (with a warning), never wrong. Only
    LighterGlue has the layers it needs: with another matcher the stage is off."""
    if not config.gate or config.gate_exit_layer <= 0:
        return None
    if config.matcher != "xfeat_lighterglue":
        log.info("reid.gate_exit_layer: %s has no layers to stop after; the gate's exit stage is off", config.matcher)
        return None
    if config.gate_exit_threshold is not None:
        return float(config.gate_exit_threshold)
    path, data = _calibration(config)
    if "gate_exit_threshold" in data and int(data.get("gate_exit_layer", -1)) != config.gate_exit_layer:
        log.warning(
            "%s: the exit stage was calibrated after layer %s, the config asks for %d: the exit stage is off",
            path,
            data.get("gate_exit_layer"),
            config.gate_exit_layer,
        )
        return None
    # a file without the key was calibrated on all keypoints (before the key existed)
    if "gate_exit_threshold" in data and int(data.get("gate_exit_keypoints", 0)) != config.gate_exit_keypoints:
        log.warning(
            "%s: the exit stage was calibrated on %s keypoints, the config asks for %s: the exit stage is off",
            path,
            int(data.get("gate_exit_keypoints", 0)) or "all",
            config.gate_exit_keypoints or "all",
        )
        return None
    return _threshold_in_file(config, path, data, "gate_exit_threshold", "the gate's exit stage is off")


def _threshold_in_file(config: ReIDConfig, path: Path, data: dict, key: str, off: str) -> float | None:
    """A gate stage's threshold from its calibration file: None (with a warning saying ``off``)
    when the file has none or the config's explicit tau is below the one it was calibrated for."""
    if key not in data:
        log.warning("reid.gate is on but %s has no %s (run `imgnav calibrate --gate`): %s", path, key, off)
        return None
    if config.tau is not None and float(config.tau) < float(data["tau"]):
        log.warning(
            "reid.tau %.4g is below the tau %.4g the %s in %s was calibrated for: %s",
            config.tau,
            float(data["tau"]),
            key,
            path,
            off,
        )
        return None
    return float(data[key])


def matcher_key(config: ReIDConfig) -> tuple:
    """What makes two configs' matchers interchangeable (a cache of matchers is keyed by it):
    everything ``make_matcher`` builds from, the exit layer included."""
    return (config.matcher, config.max_side_px, config.min_confidence, config.sift_ratio, *_exit_settings(config))


def _exit_settings(config: ReIDConfig) -> tuple[int, int]:
    """(exit layer, exit keypoints) the matcher is built with: the stage exists only where the gate
    runs or is recorded (0, 0: none)."""
    exit_layer = config.gate_exit_layer if (config.gate or config.gate_shadow) else 0
    return exit_layer, (config.gate_exit_keypoints if exit_layer else 0)


def make_matcher(config: ReIDConfig) -> Matcher:
    if config.matcher != "sift":
        import torch

        torch.set_num_threads(max(1, config.num_threads))
    if config.matcher == "xfeat_lighterglue":
        from agent.reid.xfeat import XFeatLighterGlue

        exit_layer, exit_keypoints = _exit_settings(config)
        return XFeatLighterGlue(
            config.max_side_px, config.min_confidence, exit_layer=exit_layer, exit_keypoints=exit_keypoints
        )
    if config.matcher == "aliked_lightglue":
        from agent.reid.aliked import AlikedLightGlue

        return AlikedLightGlue(config.max_side_px, config.min_confidence)
    if config.matcher == "sift":
        from agent.reid.sift import SiftRatio

        return SiftRatio(config.max_side_px, config.sift_ratio)
    raise ValueError(f"unknown matcher {config.matcher!r}")


@dataclass(frozen=True, slots=True, eq=False)
class ReIDResult:
    """One egocentric frame against the goal.

    goal_xy / obs_xy: (M, 2) float32 pixel coordinates of the matched keypoints.
    """

    score: float
    matches: Matches
    goal_xy: np.ndarray
    obs_xy: np.ndarray
    extract_ms: float
    match_ms: float
    full_matcher: bool = True  # False: the gate scored the frame 0 without the full matcher
    gate_score: float | None = None  # the gate's cheap score (None: gate off)
    gate_ms: float = 0.0
    # the exit stage's score (LighterGlue's head after the exit layer; None: not computed, the
    # first stage already stopped the frame or the stage is off)
    exit_score: float | None = None
    # the frame's own keypoints and descriptors, as extracted for this comparison (None: not
    # kept); the agent's memory of a home keeps them (``agent.memory``) without extracting twice
    features: Features | None = None


class ReIdentifier:
    """Goal features once per run; per frame: extract, gate, and (when the gate lets the frame
    through, or the gate is off) the full matcher."""

    def __init__(
        self, config: ReIDConfig = ReIDConfig(), matcher: Matcher | None = None, min_score_ratio: float = 1.0
    ) -> None:
        """``min_score_ratio``: the lowest full score that matters to the caller, as a share of
        tau (1.0: detections only; the policy's potential evidence uses less). The gate's
        threshold was calibrated to keep the frames that reach tau, from a bound linear in the
        score (gate score >= r x full score at its 1% quantile, over frames >= tau/2), so it is
        scaled by the same share: the frames that reach ``min_score_ratio x tau`` pass."""
        self.config = config
        self.matcher = matcher if matcher is not None else make_matcher(config)
        self.goal: Features | None = None
        if not 0.0 < min_score_ratio <= 1.0:
            raise ValueError(f"min_score_ratio {min_score_ratio} must be in (0, 1]")
        if min_score_ratio < 0.5 and config.gate:
            log.warning(
                "re-ID gate scaled to %.2f of tau: below the tau/2 its bound was measured from", min_score_ratio
            )
        base = resolve_gate_threshold(config)
        self.gate_threshold = None if base is None else base * min_score_ratio
        self._gate = MNNGate(config.gate_min_cosine) if (config.gate or config.gate_shadow) else None
        # the second stage, scaled like the first (its bound is linear in the score as well)
        exit_base = resolve_exit_threshold(config)
        matcher_exit: int | None = getattr(self.matcher, "exit_layer", None)  # only LighterGlue has one
        if exit_base is not None and matcher_exit is None:
            log.info("the injected matcher %s has no exit layer: the gate's exit stage is off", self.matcher.name)
            exit_base = None
        if exit_base is not None and matcher_exit != config.gate_exit_layer:
            raise ValueError(
                f"the re-ID gate's exit stage is calibrated after layer {config.gate_exit_layer}, the "
                f"matcher exits after layer {matcher_exit} (agent.reid.identifier.make_matcher)"
            )
        matcher_keypoints = int(getattr(self.matcher, "exit_keypoints", 0))
        if exit_base is not None and matcher_keypoints != config.gate_exit_keypoints:
            raise ValueError(
                f"the re-ID gate's exit stage is calibrated on {config.gate_exit_keypoints or 'all'} keypoints, "
                f"the matcher's on {matcher_keypoints or 'all'} (agent.reid.identifier.make_matcher)"
            )
        self.exit_threshold = None if exit_base is None else exit_base * min_score_ratio
        # shadow recordings (gate off) report the exit stage's score of every frame too
        self._shadow_exit = bool(config.gate_shadow and matcher_exit)

    def set_goal(self, goal_rgb: np.ndarray) -> Features:
        self.goal = self.matcher.extract(goal_rgb, self.config.goal_max_keypoints)
        if self._gate is not None:
            self._gate.set_goal(self.goal.descriptors)
        log.debug("goal image: %d keypoints", len(self.goal))
        return self.goal

    def extract(self, rgb: np.ndarray) -> Features:
        return self.matcher.extract(rgb, self.config.obs_max_keypoints)

    def compare(self, obs_rgb: np.ndarray, use_gate: bool = True) -> ReIDResult:
        """Score a frame against the goal: extract; the gate's first stage (MNN count) and, past
        it, LighterGlue, stopped after its exit layer when the exit stage's score is below its
        threshold (the frame scores 0 either way). ``use_gate=False`` runs the full matcher
        whatever the gate says (the caller knows the frame matters: the agent near a candidate);
        the first stage's score is still reported."""
        if self.goal is None:
            raise RuntimeError("set_goal() first")
        t0 = time.perf_counter()
        obs = self.extract(obs_rgb)
        t1 = time.perf_counter()
        gate_score = self._gate.score(obs.descriptors) if self._gate is not None else None
        t_gate = time.perf_counter()

        def skipped(match_ms: float, exit_score: float | None = None) -> ReIDResult:
            # a frame the gate stopped (first stage, or LighterGlue's exit layer): score 0, no matches
            return ReIDResult(0.0, Matches.empty(), _EMPTY_XY, _EMPTY_XY, (t1 - t0) * 1e3, match_ms, full_matcher=False,
                              gate_score=gate_score, gate_ms=(t_gate - t1) * 1e3, exit_score=exit_score,
                              features=obs)  # fmt: skip

        if use_gate and self.gate_threshold is not None and gate_score is not None and gate_score < self.gate_threshold:
            return skipped(0.0)
        exit_on = use_gate and self.exit_threshold is not None
        if exit_on:
            m = self.matcher.match(self.goal, obs, exit_below=(self.config.score, self.exit_threshold))  # type: ignore[call-arg]
        else:
            m = self.matcher.match(self.goal, obs)
        t2 = time.perf_counter()
        if self._shadow_exit and not exit_on:
            self.matcher.exit_stage(self.goal, obs)  # type: ignore[attr-defined]
        exit_scores = getattr(self.matcher, "exit_scores", None)
        exit_score = None if exit_scores is None else float(exit_scores[self.config.score])
        if exit_on and self.matcher.exited:  # type: ignore[attr-defined]
            return skipped((t2 - t_gate) * 1e3, exit_score)
        return ReIDResult(
            score=score(m, self.config.score),
            matches=m,
            goal_xy=self.goal.keypoints_xy[m.idx_goal],
            obs_xy=obs.keypoints_xy[m.idx_obs],
            extract_ms=(t1 - t0) * 1e3,
            match_ms=(t2 - t_gate) * 1e3,
            full_matcher=True,
            gate_score=gate_score,
            gate_ms=(t_gate - t1) * 1e3,
            exit_score=exit_score,
            features=obs,
        )
