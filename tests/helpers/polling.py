"""Waiting for a condition with a deadline (tests synchronise on state, never on sleeps)."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any


def poll(
    fn: Callable[[], Any], until: Callable[[Any], bool] = bool, timeout_s: float = 30.0, what: str = "condition"
) -> Any:
    """Call ``fn`` until ``until(value)`` holds and return that value; a deadline, not a sleep,
    bounds the wait (generous: the suite runs on two loaded cores)."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = fn()
        if until(value):
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"{what} not reached within {timeout_s} s; last value {value!r}")
        time.sleep(0.02)
