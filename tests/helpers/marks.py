"""Marking tests from a conftest.py, for folders whose test files are edited by others."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import pytest


def mark_slow(items: Iterable[pytest.Item], folder: Path, names: Iterable[str]) -> None:
    """Mark ``slow`` the tests in ``folder`` named ``<file>::<function>`` in ``names`` (every
    parametrisation of the function). A name that is no longer collected is simply not used."""
    wanted = set(names)
    for item in items:
        if item.path.parent == folder and f"{item.path.name}::{getattr(item, 'originalname', item.name)}" in wanted:
            item.add_marker(pytest.mark.slow)
