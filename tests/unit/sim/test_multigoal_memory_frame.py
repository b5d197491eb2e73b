"""The frame of a multi-goal sequence run with a memory of the home (issue 31, ``--memory``): a
later subtask's poses are in the first subtask's start frame, its origin there is the chain of
the believed (never the true) end poses, and the failure attribution reads the agent's poses,
goal points, candidates and map in that frame. A tiny hand-made room, scripted agents and
hand-made records: every expected value is computed here from the world and the beliefs."""

from __future__ import annotations

import argparse
import math
from types import SimpleNamespace

import numpy as np
import pytest

from agent.memory import HomeMemory
from agent.types import Action, AgentRecord, CandidateInfo, MapSnapshot, Observation, Pose2D
from sim.backend import SimBackend
from sim.evaluation.modiin import Attribution
from sim.evaluation.multigoal import SharedHomeMemory, run_sequence
from sim.evaluation.registry import AgentSpec
from sim.realism import Realism, get_profile
from sim.sequences import SequenceEpisode, SequenceGoal
from sim.simple_homes import box_object, room_home
from sim.world import SimWorld
from tests.helpers.eval_args import modiin_args

GOAL_IMAGE = np.full((64, 64, 3), 128, np.uint8)
COUCH_XY = (5.0, 2.0)  # instance 0, footprint x 4.6..5.4, y 1.2..2.8
NOISY = Realism(get_profile("stretch", ["actuation", "pose"]), seed=1)  # moves slip, odometry drifts


@pytest.fixture(scope="module")
def world():
    w = SimWorld(
        room_home(
            6.0,
            4.0,
            objects=[
                box_object(0, "couch", COUCH_XY, (0.8, 1.6, 0.8)),
                box_object(1, "chair", (1.0, 3.0), (0.6, 0.6, 0.9), material="wood"),
            ],
        )
    )
    yield w
    w.close()


def _snapshot(points_xy: np.ndarray, res: float = 0.05) -> MapSnapshot:
    """A map whose obstacle cells hold these points (the agent's frame)."""
    lo = np.floor(points_xy.min(axis=0) / res) * res - res
    hi = points_xy.max(axis=0) + 2 * res
    shape = (int(math.ceil((hi[1] - lo[1]) / res)), int(math.ceil((hi[0] - lo[0]) / res)))
    obstacle = np.zeros(shape, bool)
    ij = np.floor((points_xy - lo) / res).astype(int)
    obstacle[ij[:, 1], ij[:, 0]] = True
    z = np.zeros_like(obstacle)
    return MapSnapshot(res, (float(lo[0]), float(lo[1])), obstacle, z, z, z, z, z)


def test_a_later_subtasks_attribution_reads_the_agent_in_the_memorys_frame(world: SimWorld) -> None:
    """A subtask whose start lies at a far, turned origin in the memory's frame, under pose noise:
    the goal point the agent put on the couch is on it, the phantom obstacles are those in open
    floor, the pose error is its belief against the truth; the start frame would get all wrong."""
    start = Pose2D(2.0, 1.0, math.pi / 2)  # the subtask's true start
    origin = Pose2D(10.0, -7.0, 2.0)  # its start in the memory's frame (the agent's belief)
    b = SimBackend(
        world,
        GOAL_IMAGE,
        start,
        goal_instance_id=0,
        viewpoints_xy_m=np.array([[4.3, 2.0]]),
        shortest_path_m=2.0,
        max_steps=10,
        realism=NOISY,
        frame_origin=origin,
    )
    a = Attribution(modiin_args(), SimpleNamespace(goal_instance_id=0), b.oracle)
    obs = b.reset()
    assert obs.pose == origin  # the belief goes on in the memory's frame, not at (0, 0, 0)

    def agent_frame(world_xy: list[tuple[float, float]]) -> np.ndarray:
        """Where the agent puts world points seen from its start: their place relative to the
        robot (truly at ``start``), from where it believes it stands (``origin``)."""
        return origin.transform_xy(start.inverse().transform_xy(np.array(world_xy, float)))

    goal_pt = agent_frame([COUCH_XY])
    # obstacle cells: two in open floor (phantoms), one in the wall at x = 0, one in the couch
    obstacles = agent_frame([(3.0, 3.0), (4.0, 0.8), (0.0, 2.0), (5.0, 1.5)])
    snap = _snapshot(obstacles)
    cand = CandidateInfo(0, "confirmed", (float(goal_pt[0, 0]), float(goal_pt[0, 1])), 1, 100.0, 0.0)
    expected_error = []
    for k, action in enumerate([Action.MOVE_FORWARD, Action.MOVE_FORWARD, Action.TURN_LEFT, Action.MOVE_FORWARD]):
        believed, true = b.estimate_world, b.pose_world  # the belief in the world, by the simulator
        expected_error.append(math.hypot(believed.x_m - true.x_m, believed.y_m - true.y_m))
        record = AgentRecord(
            step=k,
            action=action,
            pose=obs.pose,
            mode="approach",
            reason="",
            goal_detected=True,
            goal_points_xyz=np.array([[goal_pt[0, 0], goal_pt[0, 1], 0.4]], np.float32),
            map=snap,
            candidates=(cand,),
        )
        a.on_step(obs, action, record)
        b.apply(action)
        obs = b.observe()
    assert max(expected_error) > 0.0  # the belief is not the truth
    assert a.pose_error_m == pytest.approx(expected_error, abs=1e-9)
    out = a.finish({"success": False})
    m = out["modiin"]
    assert m["candidate_to_goal_m"] == 0.0 and m["candidates"][0]["to_goal_m"] == 0.0
    assert m["candidate_on_goal_steps"] == 4
    assert m["ghost_obstacle_cells"] == 2
    assert out["failure_cause"] == "local_navigation"  # found, localised on the goal, not reached
    # the run's start frame (what a single-goal run uses) would put them far off the home
    wrong = start.transform_xy(goal_pt)[0]
    assert math.dist(wrong, COUCH_XY) > 5.0
    assert b.oracle.frame_world != b.oracle.start_pose_world


class _Walker:
    """Walks a fixed script (so only the budget ends a subtask) and keeps the poses it is given."""

    SCRIPT = (Action.MOVE_FORWARD, Action.TURN_LEFT, Action.MOVE_FORWARD, Action.TURN_RIGHT)

    def __init__(self, made: list[_Walker]) -> None:
        self.home_memory: HomeMemory | None = None
        self.poses: list[Pose2D] = []
        self._record: AgentRecord | None = None
        made.append(self)

    def reset(self, goal_image: np.ndarray) -> None:
        self.poses = []

    def act(self, obs: Observation) -> Action:
        action = self.SCRIPT[len(self.poses) % len(self.SCRIPT)]
        self.poses.append(obs.pose)
        self._record = AgentRecord(step=obs.step, action=action, pose=obs.pose, mode="explore", reason="")
        return action

    @property
    def last_record(self) -> AgentRecord | None:
        return self._record


def _sequence() -> SequenceEpisode:
    goals = tuple(
        SequenceGoal(i, cat, f"goals/m-g{k}.png", vp, kind, of)
        for k, (i, cat, vp, kind, of) in enumerate(
            [
                (0, "couch", ((4.3, 2.0),), "new", None),
                (1, "chair", ((1.6, 3.0),), "new", None),
                (0, "couch", ((4.3, 2.0),), "repeat", 0),
            ]
        )
    )
    return SequenceEpisode("m", "val", -1, Pose2D(1.0, 1.0, 0.0), 3.3, goals)


@pytest.mark.slow  # three subtasks of six rendered steps, three times: seconds
def test_the_memorys_frame_is_the_chain_of_believed_end_poses(world: SimWorld) -> None:
    """With ``--memory`` under pose noise: every subtask's agent gets the sequence's one memory,
    and its first pose is its origin in the first subtask's frame, the composition of the believed
    ends before it (from the records' estimated trajectories), not of the true ones. Without
    ``--memory`` every subtask starts at (0, 0, 0) and records no memory."""
    seq = _sequence()
    made: list[_Walker] = []
    spec = AgentSpec("test-walker", "walks", lambda args, oracle: _Walker(made), make_memory=lambda args: HomeMemory())
    args = argparse.Namespace(memory=True, subtask_budget=6, realism="stretch", realism_only=["actuation", "pose"])
    images = [GOAL_IMAGE] * 3
    rec = run_sequence(world, seq, images, spec, args)
    subs = rec["subtasks"]
    assert rec["memory"] is True and len(made) == 3 and all(s["steps"] == 6 for s in subs)
    memory = made[0].home_memory
    assert isinstance(memory, HomeMemory) and all(w.home_memory is memory for w in made)
    assert made[0].poses[0] == Pose2D() and subs[0]["memory"]["frame_origin"] == [0.0, 0.0, 0.0]
    believed_origin, true_origin = Pose2D(), Pose2D()
    for k in (1, 2):
        prev = subs[k - 1]
        start_prev = Pose2D(*prev["start_pose_world"])
        believed_end = Pose2D(*prev["trajectory"]["poses_estimate_world"][-1]).relative_to(start_prev)
        true_end = Pose2D(*prev["trajectory"]["poses_world"][-1]).relative_to(start_prev)
        believed_origin, true_origin = believed_origin.compose(believed_end), true_origin.compose(true_end)
        first = made[k].poses[0]
        assert first.distance_to(believed_origin) < 1e-3  # the records' poses are rounded to 0.1 mm
        assert abs(math.remainder(first.yaw_rad - believed_origin.yaw_rad, 2 * math.pi)) < 1e-3
        assert subs[k]["memory"]["frame_origin"] == pytest.approx([first.x_m, first.y_m, first.yaw_rad], abs=1e-4)
        assert first.distance_to(true_origin) > 5e-3  # beliefs, not the truth
    # another sequence gets another memory
    again: list[_Walker] = []
    spec2 = AgentSpec(
        "test-walker", "walks", lambda args, oracle: _Walker(again), make_memory=lambda args: HomeMemory()
    )
    run_sequence(world, seq, images, spec2, args)
    assert again[0].home_memory is not memory and all(w.home_memory is again[0].home_memory for w in again)
    # without --memory: each subtask in its own start frame, no memory anywhere
    made.clear()
    rec = run_sequence(world, seq, images, spec, argparse.Namespace(subtask_budget=6))
    assert rec["memory"] is False and all("memory" not in s for s in rec["subtasks"])
    assert [w.poses[0] for w in made] == [Pose2D()] * 3 and all(w.home_memory is None for w in made)


def test_memory_needs_an_agent_that_keeps_one() -> None:
    spec = AgentSpec("test-forgetful", "no memory", lambda args, oracle: _Walker([]))
    with pytest.raises(ValueError, match="keeps no memory"):
        SharedHomeMemory(spec, argparse.Namespace(memory=True))
