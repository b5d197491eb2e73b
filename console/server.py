"""``imgnav console``: serve the operator console (FastAPI + viser) with the simulator.

    imgnav console --host 127.0.0.1 --port 8000 [--data-dir data] [--token T]

Bound to loopback by default. Bound to another address (``--host 0.0.0.0`` so that a
phone on the same network can reach it), every request that can start or stop a run
needs the token, which is generated and logged at start unless ``--token`` (or the
environment variable IMGNAV_TOKEN) sets it. Ctrl-C stops the active run first.
"""

from __future__ import annotations

import argparse
import logging
import os
import socket
from pathlib import Path

from console.context import Console, ConsoleConfig
from console.viewer import ViewerConfig

logger = logging.getLogger(__name__)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--host", default="127.0.0.1", help="bind address (default: loopback only)")
    parser.add_argument("--port", type=int, default=8000, help="HTTP port (default: 8000)")
    parser.add_argument("--data-dir", type=Path, default=Path("data"), help="runs, database and caches (default: ./data)")
    parser.add_argument("--token", default=os.environ.get("IMGNAV_TOKEN"), help="token for starting/stopping runs (default: generated when not on loopback)")
    parser.add_argument("--viewer-port", type=int, default=8080, help="port of the live 3D viewer (viser); 0 = any free port")
    parser.add_argument("--no-viewer", action="store_true", help="do not start the live 3D viewer")
    parser.add_argument("--homes", type=int, default=2, help="number of simulator homes to prepare (default: 2)")
    parser.add_argument("--home-seed", type=int, default=None, help="scene seed of the first simulator home")
    parser.add_argument("--episodes", type=Path, default=None, help="offer the episodes of this set (imgnav episodes --out DIR) as runs")
    parser.add_argument("--stretch-host", default=None, help="offer the Stretch backend: the robot's address (stretch_ai bridge)")
    parser.add_argument("--agent-config", type=Path, default=None, help="agent YAML (default: agent/configs/sim.yaml)")


def _lan_addresses() -> list[str]:
    try:
        infos = socket.getaddrinfo(socket.gethostname(), None, family=socket.AF_INET)
    except OSError:
        return []
    return sorted({info[4][0] for info in infos if not info[4][0].startswith("127.")})


def run(args: argparse.Namespace) -> int:
    import uvicorn

    from console.agents import warm_up_async
    from console.api import create_app
    from console.providers import build_providers

    viewer = None
    if not args.no_viewer:
        viewer = ViewerConfig(host=args.host, port=args.viewer_port)
    config = ConsoleConfig(data_dir=args.data_dir, host=args.host, port=args.port, token=args.token, viewer=viewer)
    providers = build_providers(args, Path(args.data_dir).resolve())
    console = Console(config, providers)
    app = create_app(console)
    for provider in providers.values():
        prepare = getattr(provider, "prepare_async", None)
        if prepare is not None:
            prepare(console.hub)
    warm_up_async("sim")  # load the matcher while the operator takes the photo

    hosts = [args.host] if args.host not in ("0.0.0.0", "::") else ["127.0.0.1", *_lan_addresses()]
    query = f"?token={console.token}" if console.token else ""
    for host in hosts:
        logger.info("console: http://%s:%d/%s   (phone page /phone, console /console, API docs /docs)", host, args.port, query)
    if console.token:
        logger.warning("this console is reachable from the network; its token is %s", console.token)
    if console.viewer is not None:
        logger.info("live 3D viewer on port %d", console.viewer.port)
    if console.interrupted_on_start:
        logger.warning("runs interrupted by the last shutdown: %s", ", ".join(console.interrupted_on_start))
    try:
        uvicorn.run(app, host=args.host, port=args.port, log_level="info", timeout_graceful_shutdown=5)
    finally:
        console.close()  # idempotent; the app's shutdown already did this unless uvicorn failed to start
    return 0
