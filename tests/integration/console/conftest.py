"""Fixtures: a data dir whose simulator home and gallery are prepared once per session,
and a live console (real simulator, real agent, viser viewer) on a real server."""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from pathlib import Path

import pytest

from console.sim_provider import SimProvider, SimProviderConfig
from tests.helpers.console_live import HOME_SEED, LiveServer, sim_console
from tests.helpers.shared import shared_dir


@pytest.fixture(scope="session")
def sim_data_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One data dir whose simulator cache (home + gallery) is prepared once per run, shared by
    the xdist workers; read-only (tests copy its ``sim`` folder into their own data dir)."""

    def prepare(data: Path) -> None:
        provider = SimProvider(data, SimProviderConfig(home_seeds=(HOME_SEED,)))
        provider.prepare()
        ok, why = provider.available()
        assert ok, why

    return shared_dir(tmp_path_factory, "console-data", prepare)


@pytest.fixture
def data_dir(sim_data_dir: Path, tmp_path: Path) -> Path:
    """A test's own data dir: the prepared simulator cache, no runs yet."""
    data = tmp_path / "data"
    shutil.copytree(sim_data_dir / "sim", data / "sim")
    return data


@pytest.fixture
def live_console(data_dir: Path) -> Iterator[LiveServer]:
    server = LiveServer(sim_console(data_dir, viewer=True))
    yield server
    server.close()


CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
ARGS = [
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
    "--no-sandbox",  # the CI runs as root
]


@pytest.fixture(scope="module")
def browser():
    if not Path(CHROMIUM).exists():
        pytest.fail("Debian's chromium is not installed (make test installs it: apt-get install chromium)")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=ARGS, headless=True)
        try:
            yield p, b
        finally:
            b.close()
