"""Building the Mod-IIN agent for a run from a deployment YAML (agent/configs/<name>.yaml).

The matcher (keypoint network weights) is built once per process and shared by the runs:
the console executes one run at a time, so no two agents use it at once. ``warm_up`` builds
it and runs one extraction and match ahead of the first run, so an operator's first upload
does not pay for loading weights and torch's one-off set-up.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from agent.types import Agent

logger = logging.getLogger(__name__)

_matchers: dict[tuple, Any] = {}
_matchers_lock = threading.Lock()


def _shared_matcher(reid_config: Any) -> Any:
    from agent.reid.identifier import make_matcher

    key = (reid_config.matcher, reid_config.max_side_px, reid_config.min_confidence, reid_config.sift_ratio)
    with _matchers_lock:
        if key not in _matchers:
            _matchers[key] = make_matcher(reid_config)
        return _matchers[key]


def build_agent(deployment: str | Path) -> tuple[Agent, dict[str, Any]]:
    """The agent and its full configuration as plain data (stored with the run).

    ``deployment`` is a deployment name (``sim``, ``stretch``) or a YAML path. The first
    call loads the matcher's weights from the installed package (about 1 s on 2 cores);
    later calls reuse them."""
    from agent.config import load_agent_config
    from agent.policy import ModIINAgent

    config = load_agent_config(deployment)
    agent = ModIINAgent(config, matcher=_shared_matcher(config.reid))
    as_dict = dataclasses.asdict(config)
    as_dict["deployment"] = str(deployment)
    as_dict["tau_resolved"] = getattr(agent, "tau", None)
    return agent, as_dict


def warm_up(deployment: str | Path = "sim") -> float:
    """Build the shared matcher and run it once on a synthetic image pair; returns seconds."""
    from agent.config import load_agent_config

    t0 = time.perf_counter()
    config = load_agent_config(deployment)
    matcher = _shared_matcher(config.reid)
    rng = np.random.default_rng(0)
    image = (rng.random((640, 360, 3)) * 255).astype(np.uint8)
    goal = matcher.extract(image, config.reid.goal_max_keypoints)
    matcher.match(goal, matcher.extract(image[::-1].copy(), config.reid.obs_max_keypoints))
    seconds = time.perf_counter() - t0
    logger.info("agent matcher %s ready in %.1f s", config.reid.matcher, seconds)
    return seconds


def warm_up_async(deployment: str | Path = "sim") -> threading.Thread:
    def _run() -> None:
        try:
            warm_up(deployment)
        except Exception:  # the first run will build (and report) it instead
            logger.exception("matcher warm-up failed")

    thread = threading.Thread(target=_run, name="matcher-warm-up", daemon=True)
    thread.start()
    return thread
