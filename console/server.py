"""``imgnav console``: serve the operator console (FastAPI + viser) with the simulator.

    imgnav console --host 127.0.0.1 --port 8000 [--data-dir data] [--token T]

Bound to loopback by default. Bound to another address (``--host 0.0.0.0`` so that a
phone on the same network can reach it), every request that can start or stop a run
needs the token, which is generated and logged at start unless ``--token`` (or the
environment variable IMGNAV_TOKEN) sets it. Ctrl-C stops the active run first.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import os
import socket
from collections.abc import Callable
from pathlib import Path

import uvicorn

from console.context import Console, ConsoleConfig
from console.datalock import DataDirLock, DataDirLocked
from console.security import WILDCARD_BINDS, interface_addresses
from console.viewer import ViewerConfig

logger = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--host", default="127.0.0.1", help="bind address (default: loopback only)")
    parser.add_argument("--port", type=int, default=8000, help="HTTP port (default: 8000)")
    parser.add_argument(
        "--data-dir", type=Path, default=Path("data"), help="runs, database and caches (default: ./data)"
    )
    parser.add_argument(
        "--token",
        default=os.environ.get("IMGNAV_TOKEN"),
        help="token for starting/stopping runs (default: generated when not on loopback)",
    )
    parser.add_argument(
        "--viewer-port", type=int, default=8080, help="port of the live 3D viewer (viser); 0 = any free port"
    )
    parser.add_argument("--no-viewer", action="store_true", help="do not start the live 3D viewer")
    parser.add_argument("--homes", type=int, default=2, help="number of simulator homes to prepare (default: 2)")
    parser.add_argument("--home-seed", type=int, default=None, help="scene seed of the first simulator home")
    parser.add_argument(
        "--episodes", type=Path, default=None, help="offer the episodes of this set (imgnav episodes --out DIR) as runs"
    )
    parser.add_argument(
        "--stretch-host", default=None, help="offer the Stretch backend: the robot's address (stretch_ai bridge)"
    )
    parser.add_argument("--agent-config", type=Path, default=None, help="agent YAML (default: agent/configs/sim.yaml)")
    from sim.evaluation.cli import add_realism_arguments

    # the simulated robot's senses and motion (docs/realism.md); the goal is the operator's own photo,
    # so the profile's goal-photo part does not apply here
    add_realism_arguments(parser)
    parser.add_argument(
        "--allowed-host",
        action="append",
        default=[],
        metavar="NAME",
        help="another name this console is reached by (a LAN DNS name, a proxy); requests naming any other "
        "host are refused (repeatable; loopback, the bind address and this machine's addresses are always allowed)",
    )


def console_urls(host: str, port: int, token: str | None) -> list[str]:
    """The URLs to open the console with: for a wildcard bind, this machine's interface
    addresses (a phone cannot open 127.0.0.1 or a host name that resolves to loopback)."""
    query = f"?token={token}" if token else ""
    if host in WILDCARD_BINDS:
        hosts = interface_addresses() or ["127.0.0.1"]
    else:
        hosts = [f"[{host}]" if ":" in host else host]
    return [f"http://{h}:{port}/{query}" for h in hosts]


class ConsoleServer(uvicorn.Server):
    """uvicorn's server, which stops the console's run and ends its status streams as soon as it
    starts to shut down.

    uvicorn closes idle connections at once, but waits for open responses to end before it runs
    the app's lifespan shutdown (``Console.close``), and a status stream (every open console or
    phone page holds one) never ends by itself: with a page open, Ctrl-C left the run, and the
    robot, going until ``timeout_graceful_shutdown`` had passed (and a server without that
    timeout never stopped). Here the server stops accepting connections, then ``stop``
    (``Console.stop_for_shutdown``: the run, then the streams) runs on a worker thread, so that
    the loop still sends the pages the run's last events, and then uvicorn shuts down."""

    def __init__(self, config: uvicorn.Config, stop: Callable[[], None]) -> None:
        super().__init__(config)
        self._stop = stop

    async def shutdown(self, sockets: list[socket.socket] | None = None) -> None:
        for server in self.servers:
            server.close()  # no new connections (uvicorn's own shutdown begins so too)
        try:
            await asyncio.to_thread(self._stop)
        except Exception:  # uvicorn's own shutdown must still run
            logger.exception("stopping the console for the shutdown failed")
        await super().shutdown(sockets)


def run(args: argparse.Namespace) -> int:
    from console.agents import passive_openmp_wait

    passive_openmp_wait()  # before anything imports torch

    from console.agents import warm_up_async
    from console.api import create_app
    from console.providers import build_providers

    viewer = None
    if not args.no_viewer:
        viewer = ViewerConfig(host=args.host, port=args.viewer_port)
    config = ConsoleConfig(
        data_dir=args.data_dir,
        host=args.host,
        port=args.port,
        token=args.token,
        viewer=viewer,
        allowed_hosts=tuple(getattr(args, "allowed_host", None) or ()),
    )
    # The data directory's lock first: a second console stops here, before it touches anything.
    lock = DataDirLock(Path(args.data_dir).resolve())
    try:
        lock.acquire(args.host, args.port)
    except DataDirLocked as exc:
        logger.error("%s", exc)
        return 1

    built: list[Console] = []  # the console, once the app's lifespan has built it

    def build() -> Console:
        providers = build_providers(args, Path(args.data_dir).resolve())
        console = Console(config, providers, lock=lock)
        built.append(console)
        return console

    def stop_for_shutdown() -> None:
        for console in built:
            console.stop_for_shutdown()

    def ready(console: Console) -> None:
        for provider in console.providers.values():
            prepare = getattr(provider, "prepare_async", None)
            if prepare is not None:
                prepare(console.hub)
        warm_up_async("sim")  # load the matcher while the operator takes the photo
        for url in console_urls(args.host, args.port, console.token):
            logger.info("console: %s   (phone page /phone, console /console, API docs /docs)", url)
        logger.info("accepted host names: %s", ", ".join(console.allowed_hosts))
        if console.token:
            logger.warning("this console is reachable from the network; its token is %s", console.token)
        if console.viewer is not None:
            logger.info("live 3D viewer on port %d", console.viewer.port)
        if console.interrupted_on_start:
            logger.warning("runs interrupted by the last shutdown: %s", ", ".join(console.interrupted_on_start))

    app = create_app(build=build, config=config, on_ready=ready)
    server = ConsoleServer(
        uvicorn.Config(app, host=args.host, port=args.port, log_level="info", timeout_graceful_shutdown=5),
        stop_for_shutdown,
    )
    try:
        server.run()
    except KeyboardInterrupt:  # uvicorn re-raises the Ctrl-C it handled once it has shut down
        pass
    except SystemExit as exc:  # uvicorn exits when start-up fails (a port in use, ...)
        return int(exc.code) if isinstance(exc.code, int) else 1
    finally:
        lock.release()  # the console's close released it already unless start-up failed
    return 0
