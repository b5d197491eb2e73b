"""The Stretch deployment's re-ID threshold (issue 12, part 3): the operator's own calibration
``<data_dir>/calibration/stretch.json`` when present, else the packaged simulator one, and
the run's stored configuration says which tau is in force and where it came from."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pytest

from agent.config import load_agent_config
from agent.reid.identifier import calibration_path, resolve_tau
from console.agents import Deployment, deployment_calibration_path, resolve_deployment_tau
from console.context import Console, ConsoleConfig
from console.providers import build_providers
from console.stretch_provider import StretchProvider
from robot.config import StretchConfig
from tests.helpers.robot_console import any_photo, box_fake, client_for, start_run, wait_final


def write_calibration(calibration_dir: Path, tau: float = 6.0, **overrides) -> Path:
    data = {
        "matcher": "xfeat_lighterglue",
        "score": "conf",
        "tau": tau,
        "same_pairs": 40,
        "different_pairs": 300,
        "created": "2026-11-29T11:00:00Z",
        "source": "operator photos (12 photos of 4 objects)",
        "max_f": 0.8,  # the console's calibration page writes these too
        "objects": 4,
        **overrides,
    }
    path = deployment_calibration_path(calibration_dir, "stretch")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data))
    return path


def test_the_deployment_calibration_is_used_when_present(tmp_path: Path) -> None:
    path = write_calibration(tmp_path / "calibration", tau=6.0)
    config, source = resolve_deployment_tau(
        load_agent_config("stretch"), Deployment("stretch", tmp_path / "calibration")
    )
    assert resolve_tau(config.reid) == 6.0
    assert source["kind"] == "deployment_calibration" and source["path"] == str(path)
    assert (
        source["created"] == "2026-11-29T11:00:00Z" and source["same_pairs"] == 40 and source["different_pairs"] == 300
    )
    assert source["source"].startswith("operator photos") and source["max_f"] == 0.8 and source["objects"] == 4


def test_without_one_the_packaged_simulator_tau_is_used_and_said(tmp_path: Path) -> None:
    base = load_agent_config("stretch")
    config, source = resolve_deployment_tau(base, Deployment("stretch", tmp_path / "calibration"))
    packaged = json.loads(calibration_path(base.reid.matcher, base.reid.score).read_text())["tau"]
    assert resolve_tau(config.reid) == pytest.approx(packaged)
    assert source["kind"] == "packaged_simulator_calibration"
    assert "not this deployment's camera" in source["note"] and "stretch.json" in source["note"]
    # a plain deployment name (no data directory) is the packaged one too
    assert resolve_deployment_tau(base, "stretch")[1]["kind"] == "packaged_simulator_calibration"


@pytest.mark.parametrize(
    "overrides, words",
    [
        ({"score": "count"}, "calibrate again"),
        ({"tau": -1.0}, "positive"),
        ({"tau": float("nan")}, "positive"),
    ],
)
def test_an_unusable_calibration_is_an_error_not_a_silent_fallback(tmp_path: Path, overrides, words) -> None:
    write_calibration(tmp_path / "calibration", **overrides)
    with pytest.raises(ValueError, match=words):
        resolve_deployment_tau(load_agent_config("stretch"), Deployment("stretch", tmp_path / "calibration"))


def test_a_calibration_missing_keys_is_an_error(tmp_path: Path) -> None:
    path = deployment_calibration_path(tmp_path, "stretch")
    path.write_text(json.dumps({"matcher": "xfeat_lighterglue", "score": "conf", "tau": 6.0}))
    with pytest.raises(ValueError, match="lacks"):
        resolve_deployment_tau(load_agent_config("stretch"), Deployment("stretch", tmp_path))


def test_the_console_offers_the_stretch_with_its_data_directory_calibration(tmp_path: Path) -> None:
    args = argparse.Namespace(stretch_host="192.0.2.7", homes=1, home_seed=0, agent_config=None, episodes=None)
    provider = build_providers(args, tmp_path)["stretch"]
    assert isinstance(provider.agent_deployment, Deployment)
    assert provider.agent_deployment.calibration_path() == tmp_path / "calibration" / "stretch.json"


@pytest.mark.parametrize("calibrated", [True, False])
def test_a_stretch_run_records_its_tau_and_where_it_came_from(tmp_path: Path, calibrated: bool) -> None:
    data = tmp_path / "data"
    if calibrated:
        write_calibration(data / "calibration", tau=6.0)
    fake = box_fake()
    obs, action, state = fake.ports
    robot = StretchConfig(obs_port=obs, action_port=action, state_port=state, connect_timeout_s=10.0)
    provider = StretchProvider(
        "127.0.0.1", agent_deployment=Deployment("stretch", data / "calibration"), robot_config=robot
    )
    console = Console(ConsoleConfig(data_dir=data, viewer=None), {"stretch": provider})
    try:
        with client_for(console) as client:
            run_id = start_run(client, any_photo(), max_steps=1)
            done = wait_final(client, run_id, timeout_s=120)
            assert done["status"] == "finished", done
            agent_config = done["agent_config"]
            source = agent_config["tau_source"]
            if calibrated:
                assert agent_config["tau_resolved"] == 6.0
                assert source["kind"] == "deployment_calibration"
                assert source["path"] == str(data / "calibration" / "stretch.json")
            else:
                assert agent_config["tau_resolved"] > 6.0  # the simulator's, far higher
                assert source["kind"] == "packaged_simulator_calibration"
            steps = client.get(f"/api/runs/{run_id}", params={"steps": True}).json()["steps"]
            assert steps and steps[0]["reid_tau"] == pytest.approx(agent_config["tau_resolved"])
    finally:
        console.close()
        fake.close()
    assert np.isfinite(agent_config["tau_resolved"])
