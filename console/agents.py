"""Building the Mod-IIN agent for a run from a deployment YAML (agent/configs/<name>.yaml).

The matcher (keypoint network weights) is built once per process and shared by the runs:
the console executes one run at a time, so no two agents use it at once. ``warm_up`` builds
it and runs one extraction and match ahead of the first run, so an operator's first upload
does not pay for loading weights and torch's one-off set-up.

The re-ID threshold tau of a deployment (docs/architecture.md section 5: thresholds do not transfer
between cameras; the reference code used 24.5 in simulation and 6.0 on the robot):

1. ``reid.tau`` set in the deployment YAML, else
2. the deployment's own calibration ``<data_dir>/calibration/<deployment>.json`` (written
   by the console from the operator's photos: keys matcher, score, tau, same_pairs,
   different_pairs, created, source) when a ``Deployment`` names its directory, else
3. the YAML's ``reid.calibration_file``, else the packaged simulator calibration
   ``agent/calibration/<matcher>_<score>.json``.

The run's stored configuration says which (``tau_resolved``, ``tau_source``).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from agent.types import Agent

logger = logging.getLogger(__name__)


def passive_openmp_wait() -> bool:
    """Let torch's OpenMP threads sleep, not spin, while they wait for work
    (``OMP_WAIT_POLICY=PASSIVE``), unless the environment says otherwise; True if in force.

    The console's process runs more than the matcher: the simulator's renderer, the agent's
    goal-mask thread, the viewer, the web server, and on a shared machine other jobs. With
    libgomp's default (spinning at every barrier), a torch thread that loses its core stalls
    the other: one XFeat extraction took 1.36 s instead of 0.09 s at load average 7 on 2 cores.
    Only waiting changes, not the arithmetic (same results). libgomp reads the variable when
    it is loaded, so this must run before torch is imported."""
    if "torch" in sys.modules:
        in_force = os.environ.get("OMP_WAIT_POLICY", "").upper() == "PASSIVE"
        if not in_force:
            logger.warning("torch is already imported: OMP_WAIT_POLICY=PASSIVE cannot take effect in this process")
        return in_force
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    return os.environ["OMP_WAIT_POLICY"].upper() == "PASSIVE"


_matchers: dict[tuple, Any] = {}
_matchers_lock = threading.Lock()


def shared_matcher(reid_config: Any) -> Any:
    """The process-wide matcher for a re-ID config (built on first use)."""
    from agent.reid.identifier import make_matcher, matcher_key

    key = matcher_key(
        reid_config
    )  # settings that change scores (or add the exit stage's hook) get matchers of their own
    with _matchers_lock:
        if key not in _matchers:
            _matchers[key] = make_matcher(reid_config)
        return _matchers[key]


CALIBRATION_KEYS = ("matcher", "score", "tau", "same_pairs", "different_pairs", "created", "source")


@dataclasses.dataclass(frozen=True, slots=True)
class Deployment:
    """A deployment name (``stretch``) and the directory of its own calibrations
    (``<data_dir>/calibration``; None: use the packaged one)."""

    name: str
    calibration_dir: Path | None = None

    def __str__(self) -> str:
        return self.name

    def calibration_path(self) -> Path | None:
        return None if self.calibration_dir is None else deployment_calibration_path(self.calibration_dir, self.name)


def deployment_calibration_path(calibration_dir: Path, deployment: str) -> Path:
    """Where a deployment's own calibration lives: ``<data_dir>/calibration/<deployment>.json``."""
    return Path(calibration_dir) / f"{deployment}.json"


def read_deployment_calibration(path: Path, matcher: str, score: str) -> dict[str, Any]:
    """A deployment calibration file, checked: every key present, tau a positive finite
    number, for the deployment's matcher and score (a tau calibrated for another score
    means nothing here). Raises ValueError with the file's name otherwise."""
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise ValueError(f"deployment calibration {path} cannot be read: {exc}") from exc
    if not isinstance(data, dict):
        raise ValueError(f"deployment calibration {path} is not a JSON object")
    missing = [k for k in CALIBRATION_KEYS if k not in data]
    if missing:
        raise ValueError(f"deployment calibration {path} lacks {missing}")
    if (data["matcher"], data["score"]) != (matcher, score):
        raise ValueError(
            f"deployment calibration {path} is for {data['matcher']}/{data['score']}, but the deployment "
            f"uses {matcher}/{score}: calibrate again with the deployment's matcher"
        )
    tau = data["tau"]
    if isinstance(tau, bool) or not isinstance(tau, (int, float)) or not math.isfinite(tau) or tau <= 0:
        raise ValueError(f"deployment calibration {path}: tau must be a positive number, got {tau!r}")
    return data


def resolve_deployment_tau(config: Any, deployment: str | Path | Deployment) -> tuple[Any, dict[str, Any]]:
    """The agent config with the deployment's calibration wired in, and where its tau comes
    from (``tau_source``: kind, path, and the calibration's own facts when it has them)."""
    from agent.reid.identifier import calibration_path

    reid = config.reid
    if reid.tau is not None:
        return config, {"kind": "deployment_yaml", "path": None, "note": "reid.tau set in the deployment YAML"}
    own = deployment.calibration_path() if isinstance(deployment, Deployment) else None
    if own is not None and own.is_file():
        data = read_deployment_calibration(own, reid.matcher, reid.score)
        config = dataclasses.replace(config, reid=dataclasses.replace(reid, calibration_file=str(own)))
        # the calibration's own facts (dates, pair counts, source, max F ...), scalars only
        facts = {
            k: v
            for k, v in data.items()
            if k not in ("matcher", "score", "tau", "kind", "path")
            and (v is None or isinstance(v, (str, int, float, bool)))
        }
        return config, {"kind": "deployment_calibration", "path": str(own), **facts}
    if reid.calibration_file:
        return config, {"kind": "yaml_calibration_file", "path": str(reid.calibration_file)}
    packaged = calibration_path(reid.matcher, reid.score)
    note = "simulator goal pairs (imgnav calibrate), not this deployment's camera"
    if own is not None:
        note += f"; no {own} yet (calibrate from the operator's photos)"
    return config, {"kind": "packaged_simulator_calibration", "path": str(packaged), "note": note}


def build_agent(deployment: str | Path | Deployment, home_memory: Any = None) -> tuple[Agent, dict[str, Any]]:
    """The agent and its full configuration as plain data (stored with the run).

    ``home_memory``: an ``agent.memory.HomeMemory`` the agent starts from and adds to (the
    console's memory of the run's home, ``console.home_memory``); None: from nothing.

    ``deployment`` is a deployment name (``sim``, ``stretch``), a YAML path, or a
    ``Deployment`` (a name and where its own calibration lives). The first call loads the
    matcher's weights from the installed package (about 1 s on 2 cores); later calls
    reuse them."""
    from agent.config import load_agent_config
    from agent.policy import ModIINAgent

    config = load_agent_config(str(deployment) if isinstance(deployment, Deployment) else deployment)
    config, tau_source = resolve_deployment_tau(config, deployment)
    agent = ModIINAgent(config, matcher=shared_matcher(config.reid), home_memory=home_memory)
    as_dict = dataclasses.asdict(config)
    as_dict["deployment"] = str(deployment)
    as_dict["tau_resolved"] = getattr(agent, "tau", None)
    as_dict["tau_source"] = tau_source
    as_dict["home_memory"] = home_memory is not None
    logger.info(
        "agent %s: tau %s from %s (%s)", deployment, as_dict["tau_resolved"], tau_source["kind"], tau_source["path"]
    )
    return agent, as_dict


def warm_up(deployment: str | Path = "sim") -> float:
    """Build the shared matcher and run it once on a synthetic image pair; returns seconds."""
    from agent.config import load_agent_config

    t0 = time.perf_counter()
    config = load_agent_config(deployment)
    matcher = shared_matcher(config.reid)
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
