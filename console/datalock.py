"""One console per data directory: an exclusive ``flock`` on ``<data>/console.lock``.

Two consoles on one data directory corrupt each other: the second would mark the
first's live run ``interrupted`` and allow a second simultaneous run on one robot.
The lock is taken before the run store is opened. The file holds the holder's pid
and port (JSON) so that a second console can say who holds it. The kernel releases
an flock when its process dies, however it dies (SIGKILL included), so a stale
file never blocks a restart; the file itself is left in place (deleting it would
race with a console that is just opening it).
"""

from __future__ import annotations

import errno
import fcntl
import json
import logging
import os
import time
from pathlib import Path
from typing import Any

logger = logging.getLogger(__name__)

LOCK_NAME = "console.lock"


class DataDirLocked(RuntimeError):
    """Another console holds this data directory."""

    def __init__(self, data_dir: Path, holder: dict[str, Any]) -> None:
        pid = holder.get("pid", "?")
        port = holder.get("port", "?")
        host = holder.get("host", "?")
        super().__init__(
            f"the data directory {data_dir} is in use by another imgnav console (pid {pid}, "
            f"serving {host}:{port}); stop that console or start this one with another --data-dir"
        )
        self.holder = holder


class DataDirLock:
    """Held from ``acquire`` until ``release`` (or the process's end)."""

    def __init__(self, data_dir: Path) -> None:
        self.data_dir = Path(data_dir)
        self.path = self.data_dir / LOCK_NAME
        self._fd: int | None = None

    @property
    def held(self) -> bool:
        return self._fd is not None

    def acquire(self, host: str, port: int) -> None:
        """Take the lock or raise ``DataDirLocked`` naming the holder."""
        self.data_dir.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            holder = _read(fd)
            os.close(fd)
            if exc.errno in (errno.EWOULDBLOCK, errno.EACCES, errno.EAGAIN):
                raise DataDirLocked(self.data_dir, holder) from None
            raise
        info = {"pid": os.getpid(), "host": host, "port": port, "since_s": time.time()}
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps(info).encode(), 0)
        self._fd = fd

    def update(self, **fields: Any) -> None:
        """Rewrite the holder's record (e.g. the port once the server has bound it)."""
        if self._fd is None:
            return
        info = {**_read(self._fd), **fields}
        os.ftruncate(self._fd, 0)
        os.pwrite(self._fd, json.dumps(info).encode(), 0)

    def release(self) -> None:
        if self._fd is None:
            return
        fd, self._fd = self._fd, None
        try:
            os.ftruncate(fd, 0)
        finally:
            os.close(fd)  # closing the descriptor releases the flock


def _read(fd: int) -> dict[str, Any]:
    try:
        raw = os.pread(fd, 4096, 0)
        value = json.loads(raw.decode() or "{}")
        return value if isinstance(value, dict) else {}
    except (OSError, ValueError):
        return {}
