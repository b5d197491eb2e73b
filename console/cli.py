"""The ``imgnav`` command line.

Each subcommand lives in the package that owns it and exposes two functions,
``add_arguments(parser)`` and ``run(args) -> int``. They are imported lazily so
that, say, ``imgnav episodes`` does not load torch.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

# name -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "episodes": ("sim.cli_episodes", "generate an InstanceImageNav episode set (JSON + PNG goal images)"),
    "eval": ("sim.evaluation.cli", "run an agent on an episode set and write metrics"),
    "show": ("sim.cli_show", "draw a scene's top-down map, an episode and a goal-image sheet as PNG"),
    "calibrate": ("sim.evaluation.calibrate", "choose the re-ID threshold tau by max F-measure on train pairs"),
    "console": ("console.server", "serve the operator console (FastAPI + viser)"),
    "fake-stretch": ("robot.fake_cli", "serve a simulated Stretch speaking the stretch_ai ZeroMQ protocol"),
}


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="imgnav", description="Instance image-goal navigation")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module_name, help_text) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        if only == name:
            module = importlib.import_module(module_name)
            module.add_arguments(p)
            p.set_defaults(_module=module)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    # torch's OpenMP threads sleep, not spin, while they wait, in every command (before the
    # parser imports a subcommand that may import torch): `imgnav eval` runs a worker per core
    # beside the simulator's renderer, and spinning threads that lose their core stall the others
    # (console.agents.passive_openmp_wait; an explicit OMP_WAIT_POLICY wins)
    from console.agents import passive_openmp_wait

    passive_openmp_wait()
    # Import only the chosen subcommand's module (cheap start, optional deps stay optional).
    chosen = next((a for a in argv if not a.startswith("-")), None)
    parser = build_parser(only=chosen if chosen in COMMANDS else None)
    if not argv or chosen is None:
        parser.print_help()
        return 2
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    return int(args._module.run(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
