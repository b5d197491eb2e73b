"""Fixtures: a data dir whose simulator home and gallery are prepared once per session,
and a live console (real simulator, real agent, viser viewer) on a real server."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Iterator

import pytest

from console.sim_provider import SimProvider, SimProviderConfig
from console_live import HOME_SEED, LiveServer, sim_console


@pytest.fixture(scope="session")
def sim_data_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One data dir whose simulator cache (home + gallery) is prepared once per session."""
    data = tmp_path_factory.mktemp("console-data")
    provider = SimProvider(data, SimProviderConfig(home_seeds=(HOME_SEED,)))
    provider.prepare()
    ok, why = provider.available()
    assert ok, why
    return data


@pytest.fixture
def live_console(sim_data_dir: Path, tmp_path: Path) -> Iterator[LiveServer]:
    data = tmp_path / "data"
    shutil.copytree(sim_data_dir / "sim", data / "sim")  # the prepared cache; runs start empty
    server = LiveServer(sim_console(data, viewer=True))
    yield server
    server.close()
