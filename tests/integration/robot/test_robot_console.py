"""Whole runs through the console (API, run manager, store, viewer) on the fake Stretch.

The fake robot speaks the stretch_ai bridge protocol on free loopback ports; the console's
Stretch backend choice drives it with the real Mod-IIN agent (``stretch`` deployment).
Runs on a real robot are unscored, so success is checked against the fake's ground truth:
the robot's final pose in the home must be within 0.1 m of a goal viewpoint (docs/architecture.md section 1).
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from agent.types import VIEWPOINT_SUCCESS_RADIUS_M, Action, Pose2D
from console.context import Console, ConsoleConfig
from console.stretch_provider import StretchProvider
from robot.config import StretchConfig
from robot.fake_server import FakeStretch
from tests.helpers.polling import poll
from tests.helpers.robot_console import any_photo, box_fake, client_for, start_run, stretch_console, wait_final

HOME_SEED = 0  # the console's simulator home-0 (3 rooms)


# --- a whole run that reaches the goal ------------------------------------------------


@pytest.fixture(scope="module")
def home_scenario() -> Iterator[dict]:
    """The simulator home, a large goal instance, a start 1.5-2.5 m away facing away from it, a goal
    image of it and its viewpoints -- chosen deterministically from the generated home."""
    from scipy.ndimage import binary_erosion

    from sim.goals import sample_goal_images
    from sim.navigation import instance_viewpoints
    from sim.scene_gen import generate_home
    from sim.world import SimWorld

    world = SimWorld(generate_home(HOME_SEED, n_rooms=3))
    grid = world.navigable_grid(0.05)
    clear = binary_erosion(grid.navigable, iterations=5)
    xs, ys = grid.cell_centres()
    for inst in sorted(world.home.instances, key=lambda o: (o.category not in ("couch", "bed"), o.object_id)):
        cx, cy, _ = inst.center_xyz_m()
        cells = np.argwhere(clear & (np.hypot(xs - cx, ys - cy) >= 1.5) & (np.hypot(xs - cx, ys - cy) <= 2.5))
        goals = sample_goal_images(world, inst.object_id, 1, (HOME_SEED, inst.object_id)) if len(cells) else []
        viewpoints = instance_viewpoints(world, inst.object_id)
        if len(cells) and goals and len(viewpoints):
            i, j = cells[len(cells) // 2]
            x, y = float(xs[i, j]), float(ys[i, j])
            yield {
                "world": world,
                "instance": inst,
                # facing away: the agent has to look around before it sees the object
                "start": Pose2D(x, y, math.atan2(cy - y, cx - x) + math.pi),
                "goal_rgb": goals[0].rgb,
                "viewpoints": viewpoints,
            }
            world.close()
            return
    world.close()
    pytest.fail("home has no usable goal instance")


def test_console_run_on_the_fake_stretch_reaches_the_goal(home_scenario: dict, tmp_path: Path) -> None:
    from robot.fake_sim import SimFakeWorld

    fake = FakeStretch(
        SimFakeWorld(home_scenario["world"], home_scenario["start"]), obs_port=0, action_port=0, state_port=0
    )
    fake.start()
    console = stretch_console(tmp_path / "data", fake, viewer=True)
    try:
        with client_for(console) as client:
            backends = {b["name"]: b for b in client.get("/api/config").json()["backends"]}
            assert backends["stretch"]["available"] and backends["stretch"]["label"] == "Hello Robot Stretch"
            t0 = time.monotonic()
            run_id = start_run(client, home_scenario["goal_rgb"], max_steps=80)
            done = wait_final(client, run_id, timeout_s=170)
            wall_s = time.monotonic() - t0
            assert done["status"] == "finished", done
            assert done["outcome"] == "unscored" and "stopped" in done["outcome_detail"], done
            steps = client.get(f"/api/runs/{run_id}", params={"steps": True}).json()["steps"]
            assert len(steps) == done["n_steps"] > 0 and steps[-1]["action"] == Action.STOP
            # ground truth from the fake robot: stopped at a goal viewpoint
            p = fake.pose_world
            vp = home_scenario["viewpoints"]
            dist_m = float(np.min(np.hypot(vp[:, 0] - p.x_m, vp[:, 1] - p.y_m)))
            assert dist_m <= VIEWPOINT_SUCCESS_RADIUS_M, (p, dist_m)
            # the run's start-relative poses are the fake's moves, composed
            xyt = [a for a in fake.actions if "xyt" in a]
            assert len(xyt) == sum(1 for s in steps if s["action"] != Action.STOP)
            last = steps[-1]
            rel = p.relative_to(home_scenario["start"])
            assert math.hypot(last["x_m"] - rel.x_m, last["y_m"] - rel.y_m) < 1e-6
            # streamed to the viewer like a simulator run
            assert console.viewer is not None and console.viewer.n_published > 0
            print(
                f"\nconsole run on the fake Stretch: {done['outcome']} after {done['n_steps']} steps, "
                f"{dist_m:.2f} m from the nearest viewpoint; mean step {done['timings'].get('mean_step_ms', 0):.0f} ms "
                f"(agent {done['timings'].get('agent_mean_ms', {}).get('total', float('nan')):.0f} ms); wall {wall_s:.1f} s"
            )
    finally:
        console.close()
        fake.close()


# --- faults end the run with their reason recorded ------------------------------------


def _after_actions(fake: FakeStretch, n: int, act: Callable[[], None]) -> threading.Thread:
    """Trigger a fault once the fake has handled ``n`` actions (posture and head count)."""

    def watch() -> None:
        deadline = time.monotonic() + 120
        while len(fake.actions) < n and time.monotonic() < deadline:
            time.sleep(0.01)
        act()

    thread = threading.Thread(target=watch, daemon=True)
    thread.start()
    return thread


@pytest.mark.parametrize(
    "fault, knobs, trigger, reason",
    [
        ("runstopped at start", {"runstopped": True}, None, "runstopped"),
        ("not homed", {"homed": False}, None, "not_homed"),
        ("runstop mid-run", {}, ("runstopped", True), "runstopped"),
        ("silence mid-run", {}, ("silent", True), "disconnected"),
        ("dropped acks", {}, ("drop_acks", True), "ack_timeout"),
    ],
)
def test_each_fault_fails_the_run_cleanly_with_its_reason(fault, knobs, trigger, reason, tmp_path: Path) -> None:
    fake = box_fake(**knobs)
    console = stretch_console(tmp_path / "data", fake, ack_timeout_s=2.0, resend_interval_s=0.5)
    try:
        if trigger is not None:
            _after_actions(fake, 4, lambda: setattr(fake.knobs, trigger[0], trigger[1]))  # posture, head, 2 moves
        with client_for(console) as client:
            photo = np.random.default_rng(0).integers(0, 255, (300, 400, 3), dtype=np.uint8)  # any phone photo
            run_id = start_run(client, photo, max_steps=200)
            done = wait_final(client, run_id, timeout_s=90)
            assert done["status"] == "failed", done
            assert done["outcome"] == "error" and f"({reason})" in done["outcome_detail"], done
            assert f"({reason})" in done["error"]
            if trigger is None:
                assert fake.actions == [] and done["n_steps"] == 0  # refused before sending anything
            else:
                assert done["n_steps"] >= 1  # the fault came after the first moves
                # timing is kept when the loop raises (issue 12: it was recorded as 0.0)
                assert done["timings"].get("mean_step_ms", 0.0) > 0.0, done["timings"]
                assert done["timings"].get("loop_s", 0.0) > 0.0, done["timings"]
            assert console.manager.active_run_id is None  # the console is free for the next run
    finally:
        console.close()
        fake.close()


# --- how runs end: the agent's own words, and an operator stop that does not wait -----


class ScriptedAgent:
    """Plays ``actions`` and then STOPs with the record a Mod-IIN agent writes for ``stop_mode``."""

    def __init__(self, actions: list[Action], stop_mode: str = "exhausted", stop_reason: str = "") -> None:
        self.actions, self.stop_mode, self.stop_reason = list(actions), stop_mode, stop_reason
        self.last_record = None
        self._i = 0

    def reset(self, goal_image: np.ndarray) -> None:
        self._i = 0

    def act(self, obs) -> Action:
        from agent.types import AgentRecord

        action = self.actions[self._i] if self._i < len(self.actions) else Action.STOP
        self._i += 1
        mode, reason = ("explore", "scripted") if action != Action.STOP else (self.stop_mode, self.stop_reason)
        self.last_record = AgentRecord(step=obs.step, action=action, pose=obs.pose, mode=mode, reason=reason)
        return action


class ScriptedStretchProvider(StretchProvider):
    """The real Stretch provider (backend, session, outcome) with a scripted agent."""

    def __init__(self, host: str, robot_config: StretchConfig, agent: ScriptedAgent) -> None:
        super().__init__(host, robot_config=robot_config)
        self.agent = agent

    def open(self, resolved, goal_rgb):
        from console.stretch_provider import StretchSession
        from robot.backend import StretchBackend

        return StretchSession(StretchBackend(goal_rgb, self.robot_config), self.agent, {"agent": "scripted"})


def scripted_console(data_dir: Path, fake: FakeStretch, agent: ScriptedAgent, **robot: Any) -> Console:
    obs, action, state = fake.ports
    config = StretchConfig(
        host="127.0.0.1", obs_port=obs, action_port=action, state_port=state, connect_timeout_s=10.0, **robot
    )
    provider = ScriptedStretchProvider("127.0.0.1", config, agent)
    return Console(ConsoleConfig(data_dir=data_dir, viewer=None), {"stretch": provider})


def test_an_exhausted_agent_is_recorded_in_its_own_words(tmp_path: Path) -> None:
    fake = box_fake()
    why = "no reachable frontier and no goal candidate"
    console = scripted_console(
        tmp_path / "data", fake, ScriptedAgent([Action.TURN_LEFT, Action.MOVE_FORWARD], "exhausted", why)
    )
    try:
        with client_for(console) as client:
            run_id = start_run(client, any_photo(), max_steps=50)
            done = wait_final(client, run_id, timeout_s=60)
            assert done["status"] == "finished" and done["outcome"] == "unscored", done
            detail = done["outcome_detail"]
            assert "exhausted" in detail and why in detail, detail
            assert "what it took for the object" not in detail, detail
            assert "no ground truth" in detail, detail
            assert done["n_steps"] == 3 and done["timings"]["mean_step_ms"] > 0
    finally:
        console.close()
        fake.close()


def test_an_agent_that_stops_at_the_object_says_so(tmp_path: Path) -> None:
    fake = box_fake()
    why = "within stop radius, facing the goal (confirmed)"
    console = scripted_console(tmp_path / "data", fake, ScriptedAgent([Action.TURN_LEFT], "stopped", why))
    try:
        with client_for(console) as client:
            run_id = start_run(client, any_photo(), max_steps=50)
            done = wait_final(client, run_id, timeout_s=60)
            assert done["status"] == "finished" and done["outcome"] == "unscored", done
            assert "what it took for the object" in done["outcome_detail"] and why in done["outcome_detail"], done
    finally:
        console.close()
        fake.close()


def test_operator_stop_ends_the_run_while_the_robot_drops_acknowledgements(tmp_path: Path) -> None:
    """The ack timeout is far beyond the test's patience: only the stop can end this run."""
    fake = box_fake()
    agent = ScriptedAgent([Action.TURN_LEFT, Action.TURN_RIGHT] * 50)
    console = scripted_console(tmp_path / "data", fake, agent, ack_timeout_s=10_000.0, resend_interval_s=0.5)
    try:
        _after_actions(fake, 4, lambda: setattr(fake.knobs, "drop_acks", True))  # posture, head, 2 moves
        with client_for(console) as client:
            run_id = start_run(client, any_photo(), max_steps=100)
            # the client is waiting for an acknowledgement that will not come
            poll(lambda: fake.handled_step > fake.echoed_step, bool, 60, "an unacknowledged move")
            t0 = time.monotonic()
            resp = client.post(f"/api/runs/{run_id}/stop")
            assert resp.status_code == 200 and resp.json()["stopping"], resp.text
            done = wait_final(client, run_id, timeout_s=60)
            stop_s = time.monotonic() - t0
            assert done["status"] == "stopped" and done["outcome"] == "stopped", done
            assert "runstop button is the emergency stop" in done["outcome_detail"], done
            assert done["error"] is None and done["n_steps"] >= 2
            assert len([a for a in fake.actions if "xyt" in a]) == done["n_steps"] + 1  # nothing sent after the stop
            print(f"\noperator stop with acknowledgements dropped: run stopped {stop_s:.2f} s after the request")
    finally:
        console.close()
        fake.close()
