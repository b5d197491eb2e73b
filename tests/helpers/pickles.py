"""Hostile pickles for the safe unpickler's tests."""

from __future__ import annotations

import os


class RunsShell:
    """Unpickled by a plain ``pickle.loads``, it runs ``touch <marker>``: the marker file
    appearing is the proof that the pickle executed code."""

    def __init__(self, marker: str) -> None:
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))
