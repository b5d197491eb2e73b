"""The agents ``imgnav eval`` can run, as a registry of ``AgentSpec``s.

Built in: ``oracle`` (the shortest-path oracle, ``sim.oracle_agent``). Other
agents register from their own module, listed in ``PLUGIN_MODULES`` and imported
when the registry is first used; a plugin module that does not exist yet is
skipped (any other import error is raised). See ``sim.evaluation.runner`` for how
the hooks are called.
"""

from __future__ import annotations

import argparse
import importlib
import logging
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Protocol

from agent.types import Action, Agent, AgentRecord, Observation

log = logging.getLogger(__name__)

# Modules that register agents when imported (``register(AgentSpec(...))`` at import time).
PLUGIN_MODULES: tuple[str, ...] = ("sim.evaluation.modiin",)


class EpisodeObserver(Protocol):
    """Sees every step of one episode and adds fields to its record.

    on_step: called after the agent acted and before the action is applied, with the
        observation the agent saw, its action and ``agent.last_record`` (may be None).
    finish: called once the episode is over with the episode record built so far
        (metrics, trajectory, stop reason); returns extra JSON-able fields to merge
        into the record (e.g. ``{"failure_cause": "reid_false_negative"}``)."""

    def on_step(self, obs: Observation, action: Action, record: AgentRecord | None) -> None: ...

    def finish(self, episode_record: Mapping[str, Any]) -> Mapping[str, Any]: ...


@dataclass(frozen=True)
class AgentSpec:
    """How to build and observe one kind of agent in evaluation.

    make_agent(args, oracle) -> Agent: args is the parsed ``imgnav eval`` namespace
        (including this spec's own flags); oracle is the episode's ``SimOracle``. Default
        agents must ignore the oracle; oracle ablations may use it.
    add_arguments(group): adds this agent's flags to ``imgnav eval`` (prefix them with
        the agent's name, e.g. ``--modiin-variant``, to avoid clashes).
    make_observer(args, episode, oracle) -> EpisodeObserver | None: per-episode hook.
    summarize(records) -> dict: extra summary.json fields from all episode records.
    worker_init(args): runs once in every worker process (e.g. torch thread counts).
    make_memory(args) -> a memory of a home: for an agent that can keep one across the goals of a
        multi-goal sequence (``imgnav eval --memory``; ``sim.evaluation.multigoal``): one per
        sequence, set as each goal's agent's ``home_memory`` before its ``reset``. None: the
        agent has none, and ``--memory`` is refused.
    """

    name: str
    help: str
    make_agent: Callable[[argparse.Namespace, Any], Agent]
    add_arguments: Callable[[Any], None] | None = None
    make_observer: Callable[[argparse.Namespace, Any, Any], EpisodeObserver | None] | None = None
    summarize: Callable[[list[dict[str, Any]]], Mapping[str, Any]] | None = None
    worker_init: Callable[[argparse.Namespace], None] | None = None
    make_memory: Callable[[argparse.Namespace], Any] | None = None


_REGISTRY: dict[str, AgentSpec] = {}
_plugins_loaded = False


def register(spec: AgentSpec) -> None:
    if spec.name in _REGISTRY and _REGISTRY[spec.name] is not spec:
        raise ValueError(f"agent {spec.name!r} is already registered")
    _REGISTRY[spec.name] = spec


def load_plugins() -> None:
    global _plugins_loaded
    if _plugins_loaded:
        return
    _plugins_loaded = True
    for name in PLUGIN_MODULES:
        try:
            importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name != name:  # the plugin exists but something it imports does not
                raise
            log.debug("agent plugin %s not present", name)


def get_spec(name: str) -> AgentSpec:
    load_plugins()
    if name not in _REGISTRY:
        raise KeyError(f"unknown agent {name!r}; known: {sorted(_REGISTRY)}")
    return _REGISTRY[name]


def agent_names() -> list[str]:
    load_plugins()
    return sorted(_REGISTRY)


def all_specs() -> list[AgentSpec]:
    load_plugins()
    return [_REGISTRY[n] for n in sorted(_REGISTRY)]


# --- built-in: the shortest-path oracle ----------------------------------------


def _oracle_arguments(group: Any) -> None:
    group.add_argument(
        "--oracle-weight",
        type=float,
        default=None,
        help="A* heuristic weight of the oracle (1.0 = optimal on the motion lattice)",
    )


def _make_oracle(args: argparse.Namespace, oracle: Any) -> Agent:
    from sim.oracle_agent import DEFAULT_WEIGHT, OracleAgent

    weight = getattr(args, "oracle_weight", None)
    return OracleAgent(oracle, DEFAULT_WEIGHT if weight is None else weight)


register(AgentSpec("oracle", "shortest-path oracle (ground-truth map and goal)", _make_oracle, _oracle_arguments))
