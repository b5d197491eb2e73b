"""The live scene: what the viewer draws of a step, in 3D and in its side panels.

Scene (the run's start-relative frame, z up, metres):
  /map/occupancy   the agent's map layers as a textured floor plane (unknown cells transparent):
                   explored, visited, obstacles, frontiers, collisions, goal cells
  /map/obstacles   obstacle cells as a point cloud (a few heights, so walls read as walls)
  /goal/points     projected goal points (red)
  /candidates      goal candidates (potential orange, confirmed green, rejected purple: no map
                   layer has these colours, console/pictures.py)
  /plan            planned path (yellow) and /target the frontier or goal target (magenta)
  /trajectory      the path driven so far (green)
  /robot           the robot body (cylinder) and /robot_camera a frustum textured with the live RGB
Panels: status, live RGB, depth, goal photo, keypoint matches, and re-ID score against tau over
the steps. The caller holds the viewer's handles lock around every method.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

import numpy as np

from console.pictures import depth_rgb, fit_height, layers_rgb, match_picture
from console.scene_geometry import camera_rotation, rotation_to_wxyz, segments, set_segments
from console.step_schema import STEP_SCHEMA
from console.viewer.config import ViewerConfig
from console.words import step_words

if TYPE_CHECKING:
    from agent.types import CandidateInfo
    from console.session import StepRecord

CANDIDATE_RGB = {"potential": (255, 140, 0), "confirmed": (0, 180, 80), "rejected": (154, 90, 190)}
_BLANK = np.full((8, 8, 3), 200, np.uint8)  # an empty panel


class LiveScene:
    """The scene's handles and the panels; ``publish`` draws one step."""

    def __init__(self, server: Any, config: ViewerConfig) -> None:
        self.server = server
        self.config = config
        self.step_words = ""  # the words of the step drawn last ("" after ``clear``)
        self._build_scene()
        self._build_panels()

    def _build_scene(self) -> None:
        scene = self.server.scene
        scene.add_grid("/grid", width=20.0, height=20.0, cell_size=1.0, position=(0.0, 0.0, -0.01))
        self.robot = scene.add_cylinder(
            "/robot", radius=0.17, height=1.41, color=(40, 100, 230), position=(0.0, 0.0, 0.705), visible=False
        )
        self.frustum = scene.add_camera_frustum(
            "/robot_camera", fov=math.radians(68.6), aspect=360 / 640, scale=0.35, color=(40, 100, 230), visible=False
        )
        # drawn once a step has them; ``clear`` removes them
        self.trajectory: Any = None
        self.plan: Any = None
        self.goal_points: Any = None
        self.target: Any = None
        self.occupancy: Any = None
        self.obstacles: Any = None
        self.candidates: Any = None

    def _build_panels(self) -> None:
        gui = self.server.gui
        self.status = gui.add_markdown("**imgnav** - no run yet", order=0.0)
        with gui.add_folder("Camera", order=10.0):
            self.rgb_img = gui.add_image(_BLANK, label="egocentric RGB")
            self.depth_img = gui.add_image(_BLANK, label="depth (turbo, 0-5 m)")
        with gui.add_folder("Goal", order=11.0):
            self.goal_img = gui.add_image(_BLANK, label="goal photo")
            self.match_img = gui.add_image(_BLANK, label="keypoint matches (goal | view)")
        with gui.add_folder("Re-identification", order=12.0):
            self.plot = gui.add_uplot(
                data=(np.zeros(1), np.zeros(1), np.zeros(1)),
                series=(
                    {"label": "step"},
                    {"label": "score", "stroke": "#1f77b4", "width": 2},
                    {"label": "tau", "stroke": "#d62728", "width": 1, "dash": [6, 4]},
                ),
                title="re-ID score vs tau",
                scales={"x": {"time": False}},  # x is the step number, not a timestamp
                aspect=1.6,
            )

    def show_goal(self, goal_rgb: np.ndarray) -> None:
        self.goal_img.image = fit_height(goal_rgb, self.config.image_height_px)

    def clear(self) -> None:
        """Remove what a run drew (a new run, or a replay of another one)."""
        for handle in (
            self.trajectory,
            self.plan,
            self.goal_points,
            self.target,
            self.occupancy,
            self.obstacles,
            self.candidates,
        ):
            if handle is not None:
                handle.remove()
        self.trajectory = self.plan = self.goal_points = self.target = None
        self.occupancy = self.obstacles = self.candidates = None
        self.step_words = ""

    def publish(self, rec: StepRecord, with_map: bool, replay: bool = False) -> None:
        """Draw one step (pose, paths, target, candidates, panels; the map too if ``with_map``).
        ``replay``: a stored step, which keeps the camera thumbnail only."""
        r = rec.record
        scene = self.server.scene
        with self.server.atomic():
            self._publish_pose(rec)
            traj = segments(rec.trajectory_xy_m, 0.03)
            if len(traj):
                if self.trajectory is None:
                    self.trajectory = scene.add_line_segments("/trajectory", traj, (20, 150, 60), thickness=0.04)
                else:
                    set_segments(self.trajectory, traj, (20, 150, 60))
            plan = segments(np.zeros((0, 2)) if r is None else r.plan_xy_m, 0.05)
            if not len(plan):
                plan = np.zeros((1, 2, 3), np.float32)  # viser needs a segment: a zero-length one
            if self.plan is None:
                self.plan = scene.add_line_segments("/plan", plan, (250, 180, 0), thickness=0.035)
            else:
                set_segments(self.plan, plan, (250, 180, 0))
            if r is not None and r.target_xy_m is not None:
                pos = (float(r.target_xy_m[0]), float(r.target_xy_m[1]), 0.15)
                colour = (230, 30, 40) if r.target_kind == "goal" else (255, 0, 200)
                if self.target is None:
                    self.target = scene.add_icosphere("/target", radius=0.12, color=colour, position=pos)
                else:
                    self.target.position = pos
                    self.target.color = colour
                    self.target.visible = True
            elif self.target is not None:
                self.target.visible = False
            self._publish_candidates(getattr(r, "candidates", ()) if r is not None else ())
            self._publish_images(rec, replay=replay)
            if with_map:
                self._publish_map(rec)

    def _publish_candidates(self, candidates: Iterable[CandidateInfo]) -> None:
        """Goal candidates as spheres: potential orange, confirmed green, rejected purple."""
        candidates = tuple(candidates)
        pts = np.array([[c.xy_m[0], c.xy_m[1], 0.35] for c in candidates], np.float32).reshape(-1, 3)
        colours = np.array([CANDIDATE_RGB.get(str(c.state), (200, 200, 200)) for c in candidates], np.uint8)
        colours = colours.reshape(-1, 3)
        if not len(pts):
            if self.candidates is not None:
                self.candidates.visible = False
            return
        if self.candidates is None:
            self.candidates = self.server.scene.add_point_cloud(
                "/candidates", pts, colours, point_size=0.22, point_shape="circle"
            )
        else:
            self.candidates.points = pts
            self.candidates.colors = colours
            self.candidates.visible = True

    def _publish_pose(self, rec: StepRecord) -> None:
        p = rec.pose
        self.robot.position = (p.x_m, p.y_m, 0.705)
        self.robot.visible = True
        R = camera_rotation(p.yaw_rad, rec.camera_tilt_rad)
        self.frustum.wxyz = rotation_to_wxyz(R)
        self.frustum.position = (p.x_m, p.y_m, rec.camera_height_m)
        self.frustum.fov = math.radians(rec.intrinsics.vfov_deg)
        self.frustum.aspect = rec.intrinsics.width_px / rec.intrinsics.height_px
        self.frustum.image = fit_height(rec.rgb, 160)
        self.frustum.visible = True
        # The step in the words the pages use (from the one step schema); numbered from 1 as there.
        step = STEP_SCHEMA.to_json(STEP_SCHEMA.from_step(rec))
        self.step_words = step_words(step)
        self.status.content = f"**Run {rec.run_id}** - {self.step_words}"

    def _publish_images(self, rec: StepRecord, replay: bool = False) -> None:
        h = self.config.image_height_px
        self.rgb_img.image = fit_height(rec.rgb, h)
        if replay:  # a replay keeps the camera thumbnail only (no depth, no matches)
            self.depth_img.image = _BLANK
            self.match_img.image = _BLANK
        else:
            self.depth_img.image = fit_height(depth_rgb(rec.depth_m), h)
        r = rec.record
        if r is not None and not replay:
            self.match_img.image = match_picture(
                rec.goal_rgb, rec.rgb, r.matches_goal_xy, r.matches_obs_xy, height_px=h
            )
        hist = rec.reid_history
        if hist:
            steps = np.array([s for s, _, _ in hist], np.float64)
            scores = np.array([np.nan if v is None else v for _, v, _ in hist], np.float64)
            taus = np.array([np.nan if t is None else t for _, _, t in hist], np.float64)
            self.plot.data = (steps, scores, taus)

    def _publish_map(self, rec: StepRecord) -> None:
        r = rec.record
        scene = self.server.scene
        if r is not None and len(r.goal_points_xyz):
            pts = np.asarray(r.goal_points_xyz, np.float32).reshape(-1, 3)
            if self.goal_points is None:
                self.goal_points = scene.add_point_cloud("/goal/points", pts, (230, 30, 40), point_size=0.06)
            else:
                self.goal_points.points = pts
                self.goal_points.colors = np.tile(np.array([[230, 30, 40]], np.uint8), (len(pts), 1))
        if r is None or r.map is None:
            return
        snap = r.map
        known = snap.explored | snap.obstacle
        if not known.any():
            return
        ii, jj = np.nonzero(known)
        i0, i1, j0, j1 = ii.min(), ii.max() + 1, jj.min(), jj.max() + 1
        rgb = layers_rgb(snap)[i0:i1, j0:j1]
        alpha = np.where(known[i0:i1, j0:j1], 235, 0).astype(np.uint8)
        # viser draws image row 0 towards the plane's -y (OpenCV image convention), which is
        # exactly grid row 0 = lowest y: no flip.
        rgba = np.concatenate([rgb, alpha[..., None]], axis=2)
        res = snap.resolution_m
        w_m, h_m = (j1 - j0) * res, (i1 - i0) * res
        centre = (snap.origin_xy_m[0] + j0 * res + w_m / 2, snap.origin_xy_m[1] + i0 * res + h_m / 2, 0.0)
        if self.occupancy is not None:
            self.occupancy.remove()
        self.occupancy = scene.add_image(
            "/map/occupancy",
            np.ascontiguousarray(rgba),
            render_width=w_m,
            render_height=h_m,
            position=centre,
            format="png",
            cast_shadow=False,
            receive_shadow=False,
        )
        oi, oj = np.nonzero(snap.obstacle)
        if len(oi):
            xy = snap.ij_to_xy(np.stack([oi, oj], axis=1)).astype(np.float32)
            levels = np.array([0.15, 0.6, 1.05], np.float32)
            step = max(1, math.ceil(len(xy) * len(levels) / self.config.max_obstacle_points))
            xy = xy[::step]
            pts = np.concatenate(
                [np.concatenate([xy, np.full((len(xy), 1), z, np.float32)], axis=1) for z in levels], axis=0
            )
            colours = np.tile(np.array([[90, 100, 140]], np.uint8), (len(pts), 1))
            if self.obstacles is None:
                self.obstacles = scene.add_point_cloud("/map/obstacles", pts, colours, point_size=0.05)
            else:
                self.obstacles.points = pts
                self.obstacles.colors = colours
