"""An evaluation killed without a chance to clean up (SIGKILL) leaves no worker running on."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

from tests.helpers.polling import poll


def _workers_of(parent: int) -> list[int]:
    """The spawned worker processes whose parent is ``parent`` (from /proc: no psutil here)."""
    found = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
            cmd = (d / "cmdline").read_bytes()
        except OSError:
            continue
        ppid = int(stat.rsplit(")", 1)[1].split()[1])
        if ppid == parent and b"spawn_main" in cmd:
            found.append(int(d.name))
    return found


def _alive(pid: int) -> bool:
    try:
        state = (Path("/proc") / str(pid) / "stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def test_workers_stop_when_the_evaluation_is_killed(small_episode_set: Path, tmp_path: Path) -> None:
    out = tmp_path / "eval"
    cmd = [sys.executable, "-m", "console.cli", "eval", "--episodes", str(small_episode_set)]
    cmd += ["--agent", "oracle", "--workers", "2", "--out", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    workers: list[int] = []
    try:
        workers = poll(lambda: _workers_of(proc.pid), lambda w: len(w) == 2, 60, "two workers")
        os.kill(proc.pid, signal.SIGKILL)  # no finally, no handler: only the workers can notice
        proc.wait(10)
        # each worker sees its parent gone (it was re-parented) and ends within about a second
        left = poll(lambda: [w for w in workers if _alive(w)], lambda left: not left, 20, "workers ended")
        assert len(workers) == 2 and left == []
    finally:
        if proc.poll() is None:
            proc.kill()
        for w in workers:  # a failed check leaves none behind (re-parented, they are no longer its children)
            if _alive(w):
                os.kill(w, signal.SIGKILL)
