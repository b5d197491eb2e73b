"""The console's backend choices, built from the command line.

``sim`` (the PyBullet simulator) is always offered and is the default. A robot
backend is offered when it is configured (issue 5 adds the Stretch here).
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from console.session import BackendProvider
from console.sim_provider import SimProvider, SimProviderConfig

logger = logging.getLogger(__name__)


def console_realism(args: argparse.Namespace):
    """The simulator's realism profile from ``--realism`` (None: exact). The goal is the operator's
    own photo, so the profile's goal-photo part is left out."""
    from sim.evaluation.cli import realism_of

    realism = realism_of(args)
    if realism is None:
        return None
    kept = [c for c in realism.profile.components if c != "goal_photo"]
    if not kept:
        return None
    import dataclasses

    from sim.realism import get_profile

    return dataclasses.replace(realism, profile=get_profile(realism.profile.name.split("[")[0], kept))


def build_providers(args: argparse.Namespace, data_dir: Path) -> dict[str, BackendProvider]:
    n_homes = max(1, int(getattr(args, "homes", 2)))
    first = getattr(args, "home_seed", None)
    first = 0 if first is None else int(first)
    sim_config = SimProviderConfig(
        home_seeds=tuple(range(first, first + n_homes)),
        agent_config_path=getattr(args, "agent_config", None),
        episodes_dir=getattr(args, "episodes", None),
        realism=console_realism(args),
    )
    providers: dict[str, BackendProvider] = {"sim": SimProvider(data_dir, sim_config)}
    stretch_host = getattr(args, "stretch_host", None)
    if stretch_host:
        from console.agents import Deployment
        from console.stretch_provider import StretchProvider

        # the robot's tau: the operator's own calibration in the data directory, when made; the
        # agent's memory of the robot's home beside the simulator homes' (console.robot_memory)
        providers["stretch"] = StretchProvider(
            stretch_host,
            agent_deployment=Deployment("stretch", data_dir / "calibration"),
            memory_dir=data_dir / "memory",
        )
        logger.info("Stretch backend offered (robot at %s)", stretch_host)
    return providers
