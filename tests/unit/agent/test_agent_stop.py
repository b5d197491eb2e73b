"""Where the agent stops: the candidate's core weighed by its points."""

import numpy as np

from agent.localisation import Candidate
from agent.mapping import GridMap
from agent.stop_region import core_cells, core_points


def _candidate(grid, points_xyz):
    pts = np.asarray(points_xyz, np.float32)
    cells = np.unique(grid.xy_to_ij(pts[:, :2]), axis=0)
    return Candidate(
        label=0,
        points_xyz=pts,
        cells_ij=cells,
        centroid_xy_m=tuple(np.median(pts[:, :2], axis=0)),
        n_points=len(pts),
        max_score=100.0,
        n_frames=1,
    )


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
    by_points = grid.ij_to_xy(core_cells(grid, cand, 0.7))
    assert len(by_points) > 0 and by_points[:, 0].min() >= 1.95  # only the object's cells
    # (the share of its *cells* nearest the median would keep stray cells 0.4+ m in front)
    xy = grid.ij_to_xy(cand.cells_ij)
    med = np.median(cand.points_xyz[:, :2], axis=0)
    d = np.hypot(xy[:, 0] - med[0], xy[:, 1] - med[1])
    assert xy[d <= np.quantile(d, 0.7), 0].min() < 1.7
    # the core points are the share of the points nearest to their median
    core = core_points(cand, 0.7)
    assert abs(len(core) - 700) <= 2 and core[:, 0].min() >= 2.0
