"""The console's unit tests that take seconds (API fuzzing, building the real matcher) are
marked ``slow``: ``make test-fast`` leaves them out, ``make test`` runs them. A test may carry
``@pytest.mark.slow`` itself instead of being listed here."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.helpers.marks import mark_slow

SLOW = (
    "test_console_api_fuzz.py::test_no_server_error",
    "test_console_agents.py::test_runs_share_one_matcher_and_warm_up_builds_it",
)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    mark_slow(items, Path(__file__).parent, SLOW)
