"""Building the Mod-IIN agent for a run from a deployment YAML (agent/configs/<name>.yaml)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from agent.types import Agent


def build_agent(deployment: str | Path) -> tuple[Agent, dict[str, Any]]:
    """The agent and its full configuration as plain data (stored with the run).

    ``deployment`` is a deployment name (``sim``, ``stretch``) or a YAML path. The first
    call loads the matcher's weights from the installed package (about 1 s on 2 cores);
    later calls reuse them."""
    from agent.config import load_agent_config
    from agent.policy import ModIINAgent

    config = load_agent_config(deployment)
    agent = ModIINAgent(config)
    as_dict = dataclasses.asdict(config)
    as_dict["deployment"] = str(deployment)
    as_dict["tau_resolved"] = getattr(agent, "tau", None)
    return agent, as_dict
