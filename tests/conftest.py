"""Suite-wide settings: nothing is written into the checkout; every test under
tests/integration is marked ``integration`` (real PyBullet homes, servers, a browser), so that
``-m "not integration"`` leaves them out; tests sharing a module's own module-scoped fixture
form one xdist group."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import pytest

# Hypothesis keeps its example database in ./.hypothesis unless told otherwise (read when first
# needed, after this file is imported).
os.environ.setdefault("HYPOTHESIS_STORAGE_DIRECTORY", os.path.join(tempfile.gettempdir(), "imgnav-hypothesis"))
# Torch's OpenMP threads sleep, not spin, while they wait, as in `imgnav console`
# (console.agents.passive_openmp_wait): with two xdist workers on two cores, spinning threads
# stall each other (a whole console run took 68 s instead of 26 s). Only waiting changes, not
# results. libgomp reads this when torch is imported, which is after this file.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

INTEGRATION = Path(__file__).parent / "integration"


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    xdist = config.pluginmanager.hasplugin("xdist")  # absent with `-p no:xdist`: no groups
    for item in items:
        if item.path.is_relative_to(INTEGRATION):
            item.add_marker(pytest.mark.integration)
        # `make test` spreads tests over xdist workers one by one (--dist loadgroup), but
        if not xdist:
            continue
        if "browser" in getattr(item, "fixturenames", ()):
            # the browser tests run one after another: two headless Chromiums drawing the 3D
            # viewer in software at once starve each other (page timeouts at load 9)
            item.add_marker(pytest.mark.xdist_group("browser"))
        elif _uses_own_module_fixture(item):
            # tests sharing a module-scoped fixture of their own module (a Ray cluster, generated
            # episodes, a built home) stay on one worker, so that it is built once
            item.add_marker(pytest.mark.xdist_group(item.nodeid.split("::")[0]))


def _uses_own_module_fixture(item: pytest.Item) -> bool:
    info = getattr(item, "_fixtureinfo", None)
    module = getattr(getattr(item, "module", None), "__name__", None)
    if info is None or module is None:
        return False
    return any(
        d.scope == "module" and getattr(d.func, "__module__", None) == module
        for defs in info.name2fixturedefs.values()
        for d in defs
    )
