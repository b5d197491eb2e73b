"""A value computed on a thread of its own while the caller goes on (the goal mask beside the first steps)."""

from __future__ import annotations

import threading
from collections.abc import Callable

import numpy as np


class Pending:
    """``fn(arg)`` computed on a daemon thread; ``result()`` waits for it and re-raises its error."""

    def __init__(self, fn: Callable[[np.ndarray], np.ndarray], arg: np.ndarray) -> None:
        self._value: np.ndarray | None = None
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, args=(fn, arg), name="goal-mask", daemon=True)
        self._thread.start()

    def _run(self, fn: Callable[[np.ndarray], np.ndarray], arg: np.ndarray) -> None:
        try:
            self._value = fn(arg)
        except BaseException as exc:  # handed to the caller of result(), not swallowed
            self._error = exc

    def result(self) -> np.ndarray:
        self._thread.join()
        if self._error is not None:
            raise RuntimeError(f"goal-image segmentation failed: {self._error}") from self._error
        assert self._value is not None
        return self._value
