"""Marks every test under tests/integration ``integration`` (real PyBullet homes, servers, a
browser), so that ``-m "not integration"`` or ``make test-fast`` leave them out."""

from __future__ import annotations

from pathlib import Path

import pytest

INTEGRATION = Path(__file__).parent / "integration"


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if item.path.is_relative_to(INTEGRATION):
            item.add_marker(pytest.mark.integration)
