"""Data built once per test run and shared by pytest-xdist's workers (a simulator cache, an
episode set): the first worker to ask builds it while the others wait, then all read it."""

from __future__ import annotations

import fcntl
import os
import shutil
from collections.abc import Callable
from pathlib import Path

import pytest


def shared_dir(tmp_path_factory: pytest.TempPathFactory, name: str, build: Callable[[Path], None]) -> Path:
    """The directory ``<run's temp root>/<name>``, filled by ``build(path)`` once per run.

    Tests must treat it as read-only (copy what they change): other workers read it at the
    same time."""
    base = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        base = base.parent  # the run's temp root, shared by its workers
    out, done = base / name, base / f"{name}.done"
    with open(base / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        if not done.exists():
            if out.exists():
                shutil.rmtree(out)  # a build that failed half-way in another worker
            build(out)
            done.touch()
    return out
