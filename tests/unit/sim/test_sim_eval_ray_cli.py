"""`--ray` flags of `imgnav eval` / `imgnav calibrate`, and Ray staying out of other commands."""

from __future__ import annotations

import argparse
import subprocess
import sys

import pytest

from sim.evaluation import cli


def _parse(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    cli.add_arguments(p)
    return p.parse_args(["--episodes", "E", "--agent", "oracle", "--out", "O", *argv])


def test_ray_options_from_flags() -> None:
    assert cli.ray_options(_parse([]), 2) is None
    o = cli.ray_options(
        _parse(
            [
                "--ray",
                "local",
                "--ray-retries",
                "3",
                "--ray-max-in-flight",
                "4",
                "--ray-runtime-env",
                '{"working_dir": "."}',
            ]
        ),
        2,
    )
    assert (o.address, o.num_cpus, o.max_retries, o.max_in_flight, o.runtime_env) == (
        "local",
        2,
        3,
        4,
        {"working_dir": "."},
    )
    assert cli.ray_options(_parse(["--ray", "10.0.0.5:6379"]), 1).address == "10.0.0.5:6379"
    with pytest.raises(ValueError):
        cli.ray_options(_parse(["--ray", "auto", "--ray-runtime-env", "[1]"]), 1)


def test_ray_is_imported_only_by_a_ray_run() -> None:
    code = (
        "import sys; import console.cli, sim.evaluation.cli, sim.evaluation.runner, sim.evaluation.calibrate, "
        "sim.evaluation.ray_backend, sim.evaluation.ray_calibration; "
        "from console.cli import main; "
        "assert 'ray' not in sys.modules, 'ray imported'"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)
