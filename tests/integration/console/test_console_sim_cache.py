"""What the console keeps between simulator runs (console.sim_cache), with the real simulator
and the real Mod-IIN agent: a second run in the same home reuses the kept start frame and
scoring data, a run in another home does not, and runs with and without the cache act and
score identically. Scoring data is computed only when the run is scored, not before the
first action."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from agent.loop import LoopStep, run_loop
from agent.types import Pose2D
from console import sim_adapter
from console.sim_cache import WorldCache
from console.sim_provider import SimProvider, SimProviderConfig
from sim import backend as sim_backend
from sim.camera import SIM_CAMERA
from sim.navigation import GRID_RESOLUTION_M, geodesic_field, instance_viewpoints, reachable_component
from tests.helpers.console_live import HOME_SEED

N_ROOMS = SimProviderConfig().n_rooms
STEPS = 4  # the look-around's first turns: frames, re-ID scores and poses to compare, and a score


class Trace:
    """The steps of a run as plain values: action, pose, the frame's checksum, re-ID score."""

    def __init__(self) -> None:
        self.steps: list[tuple] = []

    def step(self, s: LoopStep) -> None:
        score = None if s.record is None else s.record.reid_score
        self.steps.append((int(s.action), s.obs.pose.as_tuple(), int(s.obs.rgb.astype(np.int64).sum()), score))


@pytest.fixture(scope="module")
def catalog(sim_data_dir: Path):
    provider = SimProvider(sim_data_dir, SimProviderConfig(home_seeds=(HOME_SEED,)))
    home = next(iter(provider.homes.values()))
    item = home.gallery[0]
    start = next((s for s in home.starts if s.id == f"n{item.instance_id}"), home.starts[0])
    from PIL import Image

    goal = np.asarray(Image.open(sim_data_dir / "sim" / home.id / item.file).convert("RGB"))
    return home, item, start, goal


def open_run(catalog, worlds: WorldCache | None, **kw):
    home, item, start, goal = catalog
    args = dict(
        home_seed=home.seed,
        n_rooms=N_ROOMS,
        start_pose_world=start.pose_world,
        goal_rgb=goal,
        target_instance_id=item.instance_id,
        max_steps=STEPS,
        agent_config_path=None,
        worlds=worlds,
    )
    args.update(kw)
    return sim_adapter.open_session(**args)


def run(session, steps: int = STEPS, sinks: tuple = ()) -> tuple[Trace, dict]:
    trace = Trace()
    try:
        run_loop(session.backend, session.agent, steps, sinks=(trace, *sinks))
        return trace, session.outcome(None, "budget").metrics
    finally:
        session.close()


def test_same_home_reuses_kept_data_and_acts_and_scores_as_without_it(catalog, monkeypatch: pytest.MonkeyPatch) -> None:
    home, item, start, _ = catalog
    key = ("home", home.seed, N_ROOMS)
    worlds = WorldCache()
    try:
        first = open_run(catalog, worlds)
        world = first.backend.world
        assert worlds.derived_items("scoring") == [] and worlds.derived_items("start_render") == []
        trace1, metrics1 = run(first)
        assert len(worlds.derived_items("scoring")) == 1 and len(worlds.derived_items("start_render")) == 1
        kept_viewpoints = first.backend.viewpoints_world

        second = open_run(catalog, worlds)
        assert second.backend.world is world  # the home itself stays built
        frame = second.backend.reset().rgb
        frame[:] = 0  # a run's own copy: nothing it does reaches the kept frame
        trace2, metrics2 = run(second)
        assert second.backend.viewpoints_world is kept_viewpoints  # reused, not recomputed
        assert not kept_viewpoints.flags.writeable
        assert len(worlds.derived_items("scoring")) == 1 and len(worlds.derived_items("start_render")) == 1

        # the kept frame is the frame: rendered again after other views (culling state changed)
        world.render(Pose2D(start.pose_world[0], start.pose_world[1], start.pose_world[2] + 2.0), SIM_CAMERA)
        fresh = world.render(Pose2D(*start.pose_world), SIM_CAMERA)
        kept = sim_adapter.kept_start_render(worlds, key, world, Pose2D(*start.pose_world), SIM_CAMERA)()
        assert np.array_equal(kept.rgb, fresh.rgb) and np.array_equal(kept.depth_m, fresh.depth_m)
        assert np.array_equal(kept.instance_ids, fresh.instance_ids)

        # the scoring data is what the backend computed before it was kept
        free = reachable_component(world.navigable_grid(GRID_RESOLUTION_M), start.pose_world[:2])
        direct = np.asarray(instance_viewpoints(world, item.instance_id, free), float).reshape(-1, 2)
        assert np.array_equal(kept_viewpoints, direct)
        assert np.array_equal(
            second.backend.goal_field(), geodesic_field(world.navigable_grid(GRID_RESOLUTION_M), direct)
        )
    finally:
        worlds.close()

    # a world of its own, nothing kept; its scoring data is computed when the run is scored,
    # not on the way to the first action nor during the run
    calls: list[int] = []
    real = sim_backend.goal_scoring

    def counted(world, goal_instance_id, free):
        calls.append(goal_instance_id)
        return real(world, goal_instance_id, free)

    class Count:
        def __init__(self) -> None:
            self.seen: list[int] = []  # scoring computations so far, at each step

        def step(self, s: LoopStep) -> None:
            self.seen.append(len(calls))

    monkeypatch.setattr(sim_backend, "goal_scoring", counted)
    count = Count()
    trace0, metrics0 = run(open_run(catalog, None), sinks=(count,))
    assert count.seen == [0] * STEPS and calls == [item.instance_id]
    assert trace1.steps == trace2.steps == trace0.steps
    assert metrics1 == metrics2 == metrics0 and "spl" in metrics0


def test_another_home_does_not_reuse_kept_data(catalog) -> None:
    home, *_ = catalog
    worlds = WorldCache()
    try:
        run(open_run(catalog, worlds, max_steps=1), steps=1)  # scored: its budget is spent
        assert worlds.derived_items("scoring") and worlds.derived_items("start_render")
        seed = home.seed + 1
        other = worlds.get(("home", seed, N_ROOMS), lambda: sim_adapter._world(seed, N_ROOMS))
        assert worlds.derived_items("scoring") == [] and worlds.derived_items("start_render") == []
        _, _, pose = sim_adapter._starts(other, np.random.default_rng(0))[0]
        target = other.home.instances[0].object_id
        session = open_run(
            catalog, worlds, home_seed=seed, start_pose_world=pose, target_instance_id=target, max_steps=1
        )
        assert session.backend.world is other
        run(session, steps=1)
        (item,) = worlds.derived_items("scoring")
        assert item[0] == target
        assert worlds.derived_items("start_render") == [(Pose2D(*pose), SIM_CAMERA)]
    finally:
        worlds.close()
