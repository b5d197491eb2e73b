"""The console's parts, built once per process: store, event hub, run manager,
backend providers, viewer. ``Console.close`` stops the robot first.

Data directory layout (everything the console writes is under it)::

    <data>/console.sqlite3        run records (console.store)
    <data>/runs/<run id>/         per-run artifacts (console.artifacts)
    <data>/sim/                   simulator homes' gallery cache (console.sim_provider)
    <data>/calibration/<deployment>.json   tau from the operator's photos (console.calibration)
    <data>/memory/<home>.npz      the agent's memory of each home: simulator homes, the robot's
                                  (console.home_memory, console.robot_memory)
    <data>/console.lock           held by the console using this directory (console.datalock)
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from console.calibration import Calibrator
from console.datalock import DataDirLock
from console.events import EventHub
from console.manager import RunManager
from console.photos import PhotoLimits
from console.security import allowed_hosts, is_loopback, new_token
from console.session import BackendProvider
from console.store import RunStore
from console.viewer import Viewer, ViewerConfig

logger = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class ConsoleConfig:
    data_dir: Path = Path("data")
    host: str = "127.0.0.1"
    port: int = 8000
    token: str | None = None  # None: generated at start when the bind address is not loopback
    require_token: bool | None = None  # None: required exactly when not bound to loopback
    max_request_bytes: int = 30 * 1024 * 1024  # the photo limit plus form fields
    photo_limits: PhotoLimits = field(default_factory=PhotoLimits)
    viewer: ViewerConfig | None = field(default_factory=ViewerConfig)  # None: no live 3D view
    # Host names beyond the ones found automatically (loopback, the bind address, this
    # machine's addresses and names): a DNS name on the LAN, a reverse proxy's name.
    allowed_hosts: tuple[str, ...] = ()

    def token_required(self) -> bool:
        if self.require_token is not None:
            return self.require_token
        return not is_loopback(self.host) or self.token is not None


class Console:
    def __init__(
        self, config: ConsoleConfig, providers: Mapping[str, BackendProvider], lock: DataDirLock | None = None
    ) -> None:
        """``lock``: the data directory's lock, already held by the caller (``imgnav console`` takes
        it before anything else starts); None: taken here."""
        self.config = config
        self.data_dir = Path(config.data_dir).resolve()
        self.data_dir.mkdir(parents=True, exist_ok=True)
        # First of all: one console per data directory (raises DataDirLocked).
        self.lock = lock if lock is not None else DataDirLock(self.data_dir)
        if not self.lock.held:
            self.lock.acquire(config.host, config.port)
        try:
            self.token: str | None = None
            if config.token_required():
                self.token = config.token or new_token()
            self.allowed_hosts = allowed_hosts(config.host, config.allowed_hosts)
            self.store = RunStore(self.data_dir / "console.sqlite3")
            self.interrupted_on_start = self.store.mark_interrupted()
            self.hub = EventHub()
            self.providers = dict(providers)
            self.viewer: Viewer | None = None
            if config.viewer is not None:
                self.viewer = Viewer(
                    config.viewer, on_stop=self._stop_from_viewer, token=self.token, allowed_hosts=self.allowed_hosts
                )
            self.manager = RunManager(self.store, self.hub, self.data_dir, self.providers, viewer=self.viewer)
            self.calibrator = Calibrator(self.data_dir)
        except BaseException:
            self.lock.release()
            raise
        self._closed = False

    def _stop_from_viewer(self) -> str:
        run_id = self.manager.active_run_id
        if run_id is None:
            return "No run is active."
        self.manager.stop(run_id, "stopped from the 3D viewer")
        return f"Stopping run {run_id}..."

    def stop_for_shutdown(self) -> None:
        """The server has begun to shut down: stop the active run (and so the robot) while the
        pages still hear of it, then end their status streams, which the server would otherwise
        wait for before it shuts the app down (``console.server.ConsoleServer``)."""
        self.manager.shutdown()
        self.hub.close()

    def close(self) -> None:
        """Stop the robot first (the active run's worker closes its backend), then the rest."""
        if self._closed:
            return
        self._closed = True
        self.manager.shutdown()
        for provider in self.providers.values():
            close = getattr(provider, "close", None)
            if close is not None:
                close()
        if self.viewer is not None:
            self.viewer.close()
        self.hub.close()
        self.store.close()
        self.lock.release()
        logger.info("console closed")
