import math

import numpy as np

from agent.frontier import FrontierConfig, FrontierExplorer, frontier_mask
from agent.mapping import GridMap
from agent.planner import FMMPlanner
from agent.types import Pose2D
from tests.helpers.agent_scenes import observation, room_walls


def box(grid, layer, x0, y0, x1, y1, value=True):
    a = grid.xy_to_ij(np.array([[x0, y0]]))[0]
    b = grid.xy_to_ij(np.array([[x1, y1]]))[0]
    getattr(grid.layers, layer)[a[0] : b[0], a[1] : b[1]] = value


def two_door_room() -> GridMap:
    """Explored 4 x 4 m room centred at the origin, walls all round, doors east (x=2) and west (x=-2)."""
    grid = GridMap()
    box(grid, "explored", -2.1, -2.1, 2.1, 2.1)
    box(grid, "obstacle", -2.1, -2.1, 2.1, 2.1)
    box(grid, "obstacle", -2.0, -2.0, 2.0, 2.0, False)
    box(grid, "obstacle", 1.9, -0.4, 2.2, 0.4, False)  # east door
    box(grid, "obstacle", -2.2, -0.4, -1.9, 0.4, False)  # west door
    return grid


def test_frontiers_are_only_at_the_doors():
    grid = two_door_room()
    front = frontier_mask(grid)
    xy = grid.ij_to_xy(np.argwhere(front))
    assert len(xy) > 0
    assert np.all(np.abs(np.abs(xy[:, 0]) - 2.05) < 0.1)
    assert np.all(np.abs(xy[:, 1]) < 0.4)


def test_small_frontier_clusters_are_noise():
    grid = two_door_room()
    box(grid, "explored", 0.0, 0.0, 0.05, 0.05, False)  # a one-cell hole inside the room
    assert not frontier_mask(grid, min_cluster_cells=5)[grid.cell_of(Pose2D(0.0, 0.0))]


def test_nearest_by_geodesic_distance_then_next_when_reached():
    grid = two_door_room()
    planner = FMMPlanner()
    explorer = FrontierExplorer(FrontierConfig())
    pose = Pose2D(1.0, 0.0)
    choice = explorer.choose(grid, planner.distance_field(grid, pose), frontier_mask(grid))
    assert choice is not None and choice.target_xy_m[0] > 1.5  # east door is nearer
    # walk to the east door: the target is reached, blacklisted, and the west door is next
    pose = Pose2D(1.8, 0.0)
    choice = explorer.choose(grid, planner.distance_field(grid, pose), frontier_mask(grid))
    assert choice is not None and choice.target_xy_m[0] < -1.5
    assert grid.layers.frontier_blacklist[grid.cell_of(Pose2D(2.0, 0.0))]


def test_geodesic_not_euclidean():
    grid = two_door_room()
    # a wall splits the room: east door is Euclidean-near but geodesically far from (1, 1.5)
    box(grid, "obstacle", -1.0, 0.6, 2.0, 0.8)
    planner = FMMPlanner()
    explorer = FrontierExplorer()
    pose = Pose2D(1.0, 1.5)
    choice = explorer.choose(grid, planner.distance_field(grid, pose), frontier_mask(grid))
    assert choice is not None
    field = planner.distance_field(grid, pose)
    assert choice.target_xy_m[0] < -1.5, (choice, field.at(np.array([choice.target_ij])))


def test_unreachable_frontier_is_skipped():
    grid = two_door_room()
    box(grid, "obstacle", 1.4, -2.0, 1.6, 2.0)  # wall in front of the east door
    planner = FMMPlanner()
    explorer = FrontierExplorer()
    pose = Pose2D(0.5, 0.0)
    choice = explorer.choose(grid, planner.distance_field(grid, pose), frontier_mask(grid))
    assert choice is not None and choice.target_xy_m[0] < 0


def test_synthetic_room_after_look_around_has_frontier_at_door_only():
    walls = room_walls(-2.0, -2.0, 3.0, 2.0)
    east = walls[3]
    walls = walls[:3] + [(east[0], east[1], east[2], -0.5, east[4]), (east[0], 0.5, east[2], east[3], east[4])]
    walls += [(3.0, -0.5, 3.1, 0.5, 0.0)]  # nothing in the door
    grid = GridMap()
    for k in range(12):
        grid.update(observation(walls, Pose2D(0.0, 0.0, k * math.radians(30))))
    front = frontier_mask(grid)
    xy = grid.ij_to_xy(np.argwhere(front))
    assert len(xy) > 0
    # every frontier lies beyond the east door (the room itself is fully seen)
    assert np.all(xy[:, 0] > 2.9), xy[xy[:, 0] <= 2.9][:5]
