"""Suite-wide settings: nothing is written into the checkout; every test under
tests/integration is marked ``integration`` (real PyBullet homes, servers, a browser), so that
``-m "not integration"`` leaves them out.

How `make test` hands tests to its xdist workers (``--dist loadgroup``, replaced here by
``ModuleFixtureScheduling``): each test is its own work unit, except that the tests of a module
with a module-scoped fixture (a Ray cluster, a recorded episode, a browser, a home) go to one
worker together, so that the fixture is built once, not once per worker. Such modules are found
by reading their source for ``scope="module"``. (xdist's own groups, ``xdist_group`` marks, are
not seen by pytest-xdist 3.8 under pytest 9.2: it suffixes ``item._nodeid``, which pytest 9 no
longer reads. Whole files per worker, ``--dist loadfile``, left a longer tail in CI: 342 s
against 315 s.)"""

from __future__ import annotations

import os
import re
import tempfile
from functools import cache
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
    for item in items:
        if item.path.is_relative_to(INTEGRATION):
            item.add_marker(pytest.mark.integration)


_MODULE_FIXTURE = re.compile(r"""scope\s*=\s*["']module["']""")


@cache
def _has_module_fixture(path: Path) -> bool:
    try:
        return bool(_MODULE_FIXTURE.search(path.read_text(encoding="utf-8")))
    except OSError:  # not a file (a doctest id, a generated node): scheduled test by test
        return False


try:
    from xdist.scheduler import LoadScopeScheduling
except ImportError:  # pytest without xdist: nothing to schedule
    pass
else:

    class ModuleFixtureScheduling(LoadScopeScheduling):
        """One work unit per test, or per module for a module with a module-scoped fixture.
        xdist puts the larger units first (``--loadscope-reorder``, its default), so those
        modules start early instead of lengthening the tail."""

        def _split_scope(self, nodeid: str) -> str:
            module = nodeid.split("::", 1)[0]
            return module if _has_module_fixture(self.config.rootpath / module) else nodeid

    @pytest.hookimpl(optionalhook=True)
    def pytest_xdist_make_scheduler(config: pytest.Config, log: object) -> LoadScopeScheduling | None:
        if config.getvalue("dist") != "loadgroup":
            return None
        return ModuleFixtureScheduling(config, log)
