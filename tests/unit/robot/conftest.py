"""Fixtures: a fake Stretch on free loopback ports (analytic box room) and a client for it."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterator

import numpy as np
import pytest

from agent.types import Pose2D
from robot.backend import StretchBackend
from robot.config import StretchConfig
from robot.fake_server import FakeKnobs, FakeStretch
from robot.fake_world import BoxWorld

GOAL = np.full((48, 64, 3), 200, np.uint8)  # landscape, like an arbitrary phone photo


@pytest.fixture
def make_fake() -> Iterator[Callable[..., FakeStretch]]:
    started: list[FakeStretch] = []

    def make(world: BoxWorld | None = None, knobs: FakeKnobs | None = None, **kwargs) -> FakeStretch:
        fake = FakeStretch(
            world or BoxWorld(start_world=Pose2D(0.5, 0.3, 0.4)),
            obs_port=0,
            action_port=0,
            state_port=0,
            knobs=knobs or FakeKnobs(),
            **kwargs,
        ).start()
        started.append(fake)
        return fake

    yield make
    for fake in started:
        fake.close()


def client_config(fake: FakeStretch, **overrides) -> StretchConfig:
    assert fake.ports is not None
    obs, action, state = fake.ports
    base = StretchConfig(obs_port=obs, action_port=action, state_port=state, connect_timeout_s=5.0)
    return dataclasses.replace(base, **overrides)


@pytest.fixture
def make_backend() -> Iterator[Callable[..., StretchBackend]]:
    opened: list[StretchBackend] = []

    def make(fake: FakeStretch, **overrides) -> StretchBackend:
        backend = StretchBackend(GOAL, client_config(fake, **overrides))
        opened.append(backend)
        return backend

    yield make
    for backend in opened:
        backend.close()
