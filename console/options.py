"""A run's options: the form as sent, parsed once, and the typed options of each backend.

``RunForm`` holds the form fields of ``POST /api/runs`` (empty fields are absent). A
backend provider turns it into its own frozen options (``SimRunOptions``,
``StretchRunOptions``) in the request, so a bad option is a 422 before anything starts;
the run stores them serialised (``to_json``) and the worker uses the typed object.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from typing import Any, Protocol


@dataclass(frozen=True, slots=True)
class RunForm:
    home: str | None = None
    start: str | None = None
    episode: str | None = None
    gallery_item: str | None = None
    target_instance: str | None = None
    max_steps: int | None = None
    memory: str | None = None  # "on" (default) or "off": from the home's memory or not (console.home_memory)

    @staticmethod
    def of(**values: Any) -> RunForm:
        """From form values; empty strings count as not given."""
        return RunForm(**{k: v for k, v in values.items() if v not in (None, "")})

    def given(self) -> set[str]:
        return {f.name for f in fields(self) if getattr(self, f.name) is not None}


class RunOptions(Protocol):
    @property
    def max_steps(self) -> int: ...  # read-only: the options are frozen dataclasses

    def to_json(self) -> dict[str, Any]: ...


@dataclass(frozen=True, slots=True)
class SimRunOptions:
    """A simulator run: a home (by seed) and a start pose in its frame, or a stored episode."""

    home_seed: int
    start_pose_world: tuple[float, float, float]  # x_m, y_m, yaw_rad in the home frame
    max_steps: int
    home: str | None = None  # None for an episode (its home is built at full size)
    start: str | None = None  # start id, "custom" or "random"
    episode: str | None = None
    episodes_dir: str | None = None
    memory: str | None = None  # "off": this run neither starts from nor adds to the home's memory; None: it does

    def to_json(self) -> dict[str, Any]:
        out = {k: v for k, v in asdict(self).items() if v is not None}
        out["start_pose_world"] = list(self.start_pose_world)
        return out


@dataclass(frozen=True, slots=True)
class StretchRunOptions:
    """A run on the Stretch at ``host``; ``home``: the robot's home memory key (``robot-<hash>``;
    None: the console keeps no memory for the robot); ``memory`` as for the simulator."""

    host: str
    max_steps: int
    home: str | None = None
    memory: str | None = None  # "off": this run neither starts from nor adds to the robot's memory

    def to_json(self) -> dict[str, Any]:
        return {k: v for k, v in asdict(self).items() if v is not None}
