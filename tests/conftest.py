"""Suite-wide settings: nothing is written into the checkout; every test under
tests/integration is marked ``integration`` (real PyBullet homes, servers, a browser), so that
``-m "not integration"`` leaves them out. `make test` runs xdist with ``--dist loadgroup`` and no
group marks (the Makefile says why): a module's module-scoped fixture is built on each worker
that runs one of its tests. (xdist_group marks, which this file used to set to keep such tests together, are not seen
by pytest-xdist 3.8 under pytest 9.2: it suffixes ``item._nodeid``, which pytest 9 no longer
reads. Whole files per worker, ``--dist loadfile``, built them once but left a longer tail: 342 s
against 315 s for the suite in CI.)"""

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
    for item in items:
        if item.path.is_relative_to(INTEGRATION):
            item.add_marker(pytest.mark.integration)
