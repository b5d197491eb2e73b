"""Where the agent stops: the candidate's core weighed by its points, and the view check at the
stop spot (success needs the object in view from there)."""

import math

import numpy as np

from agent.localisation import Candidate
from agent.mapping import GridMap
from agent.modes import Mode
from agent.stop_region import core_cells, core_points
from agent.projection import points_in_view
from agent.types import Pose2D
from tests.helpers.agent_scenes import BoxWorld, observation, room_walls
from tests.helpers.agent_runs import oracle_agent, run_decisions


def _candidate(grid, points_xyz):
    pts = np.asarray(points_xyz, np.float32)
    cells = np.unique(grid.xy_to_ij(pts[:, :2]), axis=0)
    return Candidate(label=0, points_xyz=pts, cells_ij=cells, centroid_xy_m=tuple(np.median(pts[:, :2], axis=0)),
                     n_points=len(pts), max_score=100.0, n_frames=1)


def _thin_object_with_stray_points(rng):
    """A TV seen face on: 970 points on a 5 cm deep, 1.2 m wide strip at x 2.00-2.05, and 30
    stray points scattered 0.4-0.9 m in front of it (depth read off what stands before it)."""
    on = np.column_stack([rng.uniform(2.0, 2.05, 970), rng.uniform(-0.6, 0.6, 970), rng.uniform(0.6, 1.2, 970)])
    stray = np.column_stack([rng.uniform(1.1, 1.6, 30), rng.uniform(-0.6, 0.6, 30), rng.uniform(0.3, 0.9, 30)])
    return np.vstack([on, stray])


def test_core_by_points_keeps_the_object_and_drops_stray_cells():
    grid = GridMap()
    cand = _candidate(grid, _thin_object_with_stray_points(np.random.default_rng(0)))
    # the strip fills few cells, the stray points many: a third of the cells are stray
    xy = grid.ij_to_xy(cand.cells_ij)
    assert (xy[:, 0] < 1.7).mean() > 0.25
    by_points = grid.ij_to_xy(core_cells(grid, cand, 0.7, by="points"))
    by_cells = grid.ij_to_xy(core_cells(grid, cand, 0.7, by="cells"))
    assert len(by_points) > 0 and by_points[:, 0].min() >= 1.95  # only the object's cells
    assert by_cells[:, 0].min() < 1.7  # the cell-count core keeps stray cells 0.4+ m in front
    # the core points are the share of the points nearest to their median
    core = core_points(cand, 0.7)
    assert abs(len(core) - 700) <= 2 and core[:, 0].min() >= 2.0


def test_points_in_view_sees_an_open_face_and_not_one_behind_a_wall():
    goal = (3.0, -0.5, 3.3, 0.5, 1.0)
    face = np.array([[3.0, y, z] for y in np.linspace(-0.4, 0.4, 9) for z in np.linspace(0.2, 0.9, 8)])
    pose = Pose2D(0.0, 0.0, 0.0)
    n_in, n_seen = points_in_view(face, observation([goal], pose), margin_m=0.1, margin_frac=0.05)
    assert n_in == len(face) and n_seen == n_in
    wall = (1.5, -2.0, 1.6, 2.0, 2.5)  # between the camera and the face
    n_in, n_seen = points_in_view(face, observation([goal, wall], pose), margin_m=0.1, margin_frac=0.05)
    assert n_in == len(face) and n_seen == 0
    # turned away: nothing falls in the frame, so there is no evidence either way
    n_in, n_seen = points_in_view(face, observation([goal, wall], Pose2D(0.0, 0.0, math.pi)), margin_m=0.1, margin_frac=0.05)
    assert n_in == 0 and n_seen == 0


def _partition_world(closed: bool = False):
    """A TV-like goal (0.15 m deep) against a partition wall, with a table before it and a wall
    from the table to the room's side: from the start the only way to the goal leads round the
    table and behind the partition, where the stop region's cells are within 0.6 m of the goal
    but out of its sight (the partition is within 0.3 m of the goal, so the map's line-of-sight
    test does not count it); past the partition's end lies a spot in view of the goal."""
    walls = room_walls(-1.0, -2.5, 6.0, 2.5)
    partition = (3.35, -0.6, 3.45, 1.0, 2.5)
    table = (2.2, -0.6, 3.1, 1.8, 0.45)
    side_wall = (2.1, -2.5, 2.2, -0.6, 2.5)
    goal = (3.2, -0.5, 3.35, 0.5, 1.2)
    boxes = walls + [partition, table, side_wall]
    if closed:  # a wall from the partition to the room's side closes the spot in view off
        boxes.append((3.35, -2.5, 3.45, -0.6, 2.5))
    boxes.append(goal)
    return BoxWorld(boxes, Pose2D(0.5, 0.0, 0.0), len(boxes) - 1)


def test_a_stop_spot_with_the_goal_hidden_is_struck_off():
    world = _partition_world()
    steps = run_decisions(oracle_agent(world, look_around_turns=0, stop_rule="core", stop_radius_m=0.6), world,
                          max_steps=400)
    last, _ = steps[-1]
    # without the check the agent stops behind the partition, the goal out of sight
    assert last.mode == Mode.STOPPED and world.pose.x_m > 3.45 and not world.goal_visible(world.observe())

    world = _partition_world()
    steps = run_decisions(oracle_agent(world, look_around_turns=0, stop_rule="core", stop_radius_m=0.6,
                                       stop_needs_view=True), world, max_steps=400)
    hidden = [d for d, _ in steps if d.reason.startswith("the goal is hidden from here")]
    assert hidden and hidden[0].candidate is not None and hidden[0].action is not None
    last, rec = steps[-1]
    assert last.mode == Mode.STOPPED
    # it stopped past the partition's end, the goal in view
    assert world.pose.y_m < -0.6 and world.goal_visible(world.observe()) and world.distance_to_goal() < 1.0


def test_with_no_spot_in_view_within_reach_it_stops_where_it_can():
    # the spot past the partition's end is walled off: every reachable stop spot has the goal
    # hidden. The view check strikes them off, finds no other, and stops behind the partition
    # as without it, rather than rejecting the goal
    world = _partition_world(closed=True)
    steps = run_decisions(oracle_agent(world, look_around_turns=0, stop_rule="core", stop_radius_m=0.6,
                                       stop_needs_view=True), world, max_steps=600)
    assert any(d.reason.startswith("the goal is hidden from here") for d, _ in steps)
    last, rec = steps[-1]
    assert last.mode == Mode.STOPPED and last.reason.endswith(", hidden)")
    assert not any(c.state == "rejected" for c in rec.candidates)
    assert world.pose.x_m > 3.45 and world.distance_to_goal() < 0.6
