"""``SimBackend``: the simulator behind ``agent.types.Backend`` (docs/architecture.md section 4).

Built from a ``SimWorld`` and either an ``Episode`` (with its goal image) or a
free world start pose plus any goal image (an uploaded photo). In the second
case the target is unknown and the run is unscored, unless a known target
instance id is given, in which case viewpoints and geodesics (``GoalScoring``) are
computed when first needed (scoring, the oracle), not before the first action, and
``result()`` scores the run. A caller that keeps a world between runs may hand in
``scoring`` and ``start_render`` callables that return the same data kept from an
earlier run (the scene is static: same world, target and start, same values).

* ``reset()`` starts at the start pose; ``Observation.pose`` is relative to it, or, with
  ``frame_origin`` (the pose of this run's start in another frame), in that frame: a later goal
  of a multi-goal sequence whose agent keeps a memory of the home gets its poses in the frame of
  the sequence's first start (``sim.evaluation.multigoal``), as a robot's odometry goes on from
  one request to the next. ``SimOracle.frame_world`` is where that frame lies in the world, for
  everything that compares the agent's poses, points and map with the truth.
* ``apply(action)``: one discrete action; STOP ends the episode; so does the
  1000-step budget. Applying after the end raises ``BackendError("episode_over")``.
* ``oracle``: a separate ``SimOracle`` with ground truth (goal mask in the current
  frame, goal position, viewpoints, navigable map, world pose). Default agents are
  never given it; oracle ablations, metrics and failure analysis are.
* ``result()``: ``EpisodeMetrics`` once the episode is over (None if unscored).
* ``realism``: a ``sim.realism.Realism`` (profile and seed) puts a real robot's senses and motion
  around the exact world: the agent gets noisy frames, an estimated pose and a phone-like goal
  photo, moves land where the actuation model says; ``pose_world``, the trajectory, the oracle
  and the metrics stay true. ``estimate_trajectory_world`` is what the agent believed.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from agent.types import FORWARD_STEP_M, MAX_STEPS, TURN_ANGLE_DEG, Action, BackendError, Observation, Pose2D
from sim.camera import SIM_CAMERA, CameraSpec, Render
from sim.episodes import Episode, read_rgb
from sim.geometry import NavGrid
from sim.metrics import EpisodeMetrics, episode_metrics
from sim.navigation import GRID_RESOLUTION_M, geodesic_at, geodesic_field, instance_viewpoints, reachable_component
from sim.realism import Realism, RealismRun
from sim.world import SimWorld

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True, eq=False)
class GoalScoring:
    """What scoring a run needs about its target, for one world, target and start component.

    viewpoints_world: (N, 2) float64 world xy of the goal viewpoints reachable from the start.
    field: (H, W) float64 geodesic metres to the nearest viewpoint over the world's 0.05 m
           navigable grid (inf where unreachable); None when there is no viewpoint."""

    viewpoints_world: np.ndarray
    field: np.ndarray | None


def start_component(world: SimWorld, start_pose_world: Pose2D) -> np.ndarray:
    """(H, W) bool: the navigable component (0.05 m grid) the start pose lies in."""
    return reachable_component(world.navigable_grid(GRID_RESOLUTION_M), (start_pose_world.x_m, start_pose_world.y_m))


def goal_scoring(world: SimWorld, goal_instance_id: int, free: np.ndarray) -> GoalScoring:
    """Viewpoints of the goal instance within ``free`` (a start's component) and the geodesic
    field to them: the ray tests (~0.2 s on 2 cores) and the fast marching of a scored run."""
    viewpoints = np.asarray(instance_viewpoints(world, goal_instance_id, free), float).reshape(-1, 2)
    field = geodesic_field(world.navigable_grid(GRID_RESOLUTION_M), viewpoints) if len(viewpoints) else None
    return GoalScoring(viewpoints, field)


def _commanded(action: Action) -> Pose2D:
    """The motion an action commands, in the robot's frame."""
    if action == Action.MOVE_FORWARD:
        return Pose2D(FORWARD_STEP_M, 0.0, 0.0)
    if action == Action.TURN_LEFT:
        return Pose2D(0.0, 0.0, math.radians(TURN_ANGLE_DEG))
    if action == Action.TURN_RIGHT:
        return Pose2D(0.0, 0.0, -math.radians(TURN_ANGLE_DEG))
    return Pose2D()


class SimOracle:
    """Ground truth about the current run. Frames: ``*_world`` in the home's frame,
    ``*_start`` in the run's start-relative frame (the agent's frame unless the backend has a
    ``frame_origin``; ``frame_world`` is always the agent's)."""

    def __init__(self, backend: SimBackend) -> None:
        self._b = backend

    # --- the robot ---
    @property
    def pose_world(self) -> Pose2D:
        return self._b.pose_world

    @property
    def start_pose_world(self) -> Pose2D:
        return self._b.start_pose_world

    @property
    def frame_world(self) -> Pose2D:
        """The world pose of the frame the agent's poses (and so its map and goal points) are in:
        the start pose, or with a ``frame_origin`` the pose that origin makes of it
        (``start_pose_world * frame_origin^-1``). The pose estimate starts at the true start, so
        this holds for the agent's beliefs of this run: ``frame_world * Observation.pose`` is the
        believed pose in the world (``SimBackend.estimate_world``)."""
        return self._b.frame_world

    @property
    def world(self) -> SimWorld:
        return self._b.world

    def collides_world(self, x_m: float, y_m: float) -> bool:
        return self._b.world.collides(x_m, y_m)

    def move_world(self, pose_world: Pose2D, action: Action) -> tuple[Pose2D, bool]:
        """The simulator's exact motion model (for planners that must replay exactly)."""
        return self._b.world.move(pose_world, action)

    @property
    def navigable(self) -> NavGrid:
        """Ground-truth navigable grid (world frame, 0.05 m)."""
        return self._b.world.navigable_grid(GRID_RESOLUTION_M)

    # --- the goal ---
    @property
    def target_known(self) -> bool:
        return self._b.goal_instance_id is not None

    @property
    def goal_instance_id(self) -> int | None:
        return self._b.goal_instance_id

    @property
    def goal_category(self) -> str | None:
        tid = self._b.goal_instance_id
        return None if tid is None else self._b.world.home.instance(tid).category

    @property
    def goal_position_world(self) -> np.ndarray | None:
        """(3,) float64 centre of the goal instance's bounding box, world frame."""
        tid = self._b.goal_instance_id
        return None if tid is None else np.array(self._b.world.home.instance(tid).center_xyz_m())

    @property
    def goal_position_start(self) -> np.ndarray | None:
        """(3,) goal centre in the start-relative frame."""
        g = self.goal_position_world
        if g is None:
            return None
        xy = self._b.start_pose_world.inverse().transform_xy(g[None, :2])[0]
        return np.array([xy[0], xy[1], g[2]])

    @property
    def viewpoints_world(self) -> np.ndarray:
        """(N, 2) float64 goal viewpoints, world frame (empty when the target is unknown)."""
        return self._b.viewpoints_world

    @property
    def viewpoints_start(self) -> np.ndarray:
        return (
            self._b.start_pose_world.inverse().transform_xy(self._b.viewpoints_world)
            if len(self._b.viewpoints_world)
            else np.zeros((0, 2))
        )

    def geodesic_to_goal_m(self, x_world_m: float, y_world_m: float) -> float:
        """Shortest-path distance from a world position to the nearest viewpoint (inf if unreachable)."""
        field = self._b.goal_field()
        if field is None:
            return math.inf
        return geodesic_at(field, self.navigable, x_world_m, y_world_m)

    def goal_field(self) -> np.ndarray | None:
        """(H, W) float64 geodesic metres to the nearest viewpoint over ``navigable`` (None if unscored)."""
        return self._b.goal_field()

    # --- the current frame ---
    def instance_ids(self) -> np.ndarray:
        """(H, W) int32 instance id per pixel of the current observation (-1: none)."""
        return self._b.current_render().instance_ids

    def goal_mask(self) -> np.ndarray:
        """(H, W) bool: pixels of the goal instance in the current observation (all False if unknown).
        Read every step by the evaluation: a compare on the raw ids, no instance-id image."""
        render = self._b.current_render()
        tid = self._b.goal_instance_id
        return np.zeros(render.seg_raw.shape, dtype=bool) if tid is None else render.mask_of(tid)


class SimBackend:
    """One simulated run. The world is shared and not closed by ``close()`` unless ``owns_world``."""

    def __init__(
        self,
        world: SimWorld,
        goal_image: np.ndarray,
        start_pose_world: Pose2D,
        goal_instance_id: int | None = None,
        viewpoints_xy_m: np.ndarray | None = None,
        shortest_path_m: float | None = None,
        camera: CameraSpec = SIM_CAMERA,
        max_steps: int = MAX_STEPS,
        owns_world: bool = False,
        episode: Episode | None = None,
        scoring: Callable[[], GoalScoring] | None = None,
        start_render: Callable[[], Render] | None = None,
        realism: Realism | None = None,
        run_key: str | None = None,
        frame_origin: Pose2D | None = None,
    ) -> None:
        """``scoring``: the target's ``GoalScoring`` for this world and start (used only when
        ``goal_instance_id`` is given without ``viewpoints_xy_m``; default: ``goal_scoring``),
        called when first needed. ``start_render``: the frame at the start pose with this
        camera, called instead of rendering it (at ``reset``); it must return arrays the run
        may keep. ``realism``: the profile and seed of the run's noise (None: exact), keyed by
        ``run_key`` (default: the episode id). ``frame_origin``: the pose of the start in the frame
        ``Observation.pose`` is to be given in (None: the start itself, pose (0, 0, 0) at reset)."""
        goal_image = np.asarray(goal_image)
        if goal_image.ndim != 3 or goal_image.shape[2] != 3 or goal_image.dtype != np.uint8:
            raise ValueError("goal_image must be (h, w, 3) uint8 RGB")
        if world.collides(start_pose_world.x_m, start_pose_world.y_m):
            raise ValueError(f"start pose {start_pose_world} collides with the scene")
        self.world = world
        self.realism = realism
        self.run_key = run_key or (episode.episode_id if episode is not None else "run")
        start = realism.start(self.run_key) if realism is not None else None
        self.goal_image_rendered = goal_image
        self.goal_image = start.goal_photo(goal_image) if start is not None else goal_image
        self.start_pose_world = start_pose_world
        self.frame_origin = frame_origin
        # the world pose of the agent's frame (the start's, unless another frame is asked for)
        self.frame_world = (
            start_pose_world if frame_origin is None else start_pose_world.compose(frame_origin.inverse())
        )
        self.goal_instance_id = goal_instance_id
        self.camera = camera
        self.max_steps = max_steps
        self.owns_world = owns_world
        self.episode = episode
        self._scoring_fn: Callable[[], GoalScoring] | None = None
        self._viewpoints: np.ndarray | None = None
        if goal_instance_id is not None and viewpoints_xy_m is None:
            # Only scoring and the oracle read these, never the first action: computed on first use.
            self._scoring_fn = scoring or (
                lambda: goal_scoring(world, goal_instance_id, start_component(world, start_pose_world))
            )
        else:
            self._viewpoints = (
                np.zeros((0, 2)) if viewpoints_xy_m is None else np.asarray(viewpoints_xy_m, float).reshape(-1, 2)
            )
        self._start_render = start_render
        self._shortest_path_m = shortest_path_m
        self._field: np.ndarray | None = None
        self.oracle = SimOracle(self)
        self._closed = False
        self._reset_state()

    @classmethod
    def for_episode(cls, world: SimWorld, episode: Episode, goal_image: np.ndarray | str | Path, **kw) -> SimBackend:
        """A backend for a stored episode; ``goal_image`` is the array or its PNG path."""
        if world.home.seed != episode.scene_seed:
            raise ValueError(
                f"episode {episode.episode_id} is in scene {episode.scene_seed}, world is {world.home.seed}"
            )
        img = read_rgb(goal_image) if isinstance(goal_image, (str, Path)) else goal_image
        return cls(
            world,
            img,
            episode.start_pose_world,
            episode.goal_instance_id,
            episode.viewpoints_array(),
            episode.geodesic_distance_m,
            episode=episode,
            **kw,
        )

    def _reset_state(self) -> None:
        self.pose_world = self.start_pose_world
        self.steps = 0
        self.path_length_m = 0.0
        self.done = False
        self.called_stop = False
        self.stop_reason: str | None = None
        self.trajectory_world: list[Pose2D] = [self.start_pose_world]
        self.actions: list[Action] = []
        self._render: Render | None = None
        self._render_pose: Pose2D | None = None
        # the run's noise starts again at every reset (the same run, the same noise)
        self._noise: RealismRun | None = self.realism.start(self.run_key) if self.realism is not None else None
        if self._noise is not None:
            self._noise.start_estimate(self.start_pose_world)
        self.estimate_trajectory_world: list[Pose2D] = [self.start_pose_world]
        self._sensed: tuple[int, np.ndarray, np.ndarray] | None = None

    @property
    def viewpoints_world(self) -> np.ndarray:
        """(N, 2) float64 goal viewpoints, world frame (empty when the target is unknown)."""
        if self._viewpoints is None:
            self._resolve_scoring()
        assert self._viewpoints is not None
        return self._viewpoints

    def _resolve_scoring(self) -> None:
        assert self._scoring_fn is not None
        scoring = self._scoring_fn()
        self._viewpoints = scoring.viewpoints_world
        self._field = scoring.field

    # --- Backend protocol ---
    def reset(self) -> Observation:
        if self._closed:
            raise BackendError("closed", "backend is closed")
        self._reset_state()
        return self.observe()

    def current_render(self) -> Render:
        if self._render is None or self._render_pose != self.pose_world:
            if self._start_render is not None and self.pose_world == self.start_pose_world:
                self._render = self._start_render()
            else:
                self._render = self.world.render(self.pose_world, self.camera)
            self._render_pose = self.pose_world
        return self._render

    def observe(self) -> Observation:
        if self._closed:
            raise BackendError("closed", "backend is closed")
        r = self.current_render()
        rgb, depth = r.rgb, r.depth_m
        if self._noise is not None:
            # one draw of sensor noise per step: observing twice gives the same frame
            if self._sensed is None or self._sensed[0] != self.steps:
                noisy_depth = self._noise.depth(r.depth_m, r.rgb, self.camera.intrinsics.fx)
                self._sensed = (self.steps, self._noise.rgb(r.rgb), noisy_depth)
            rgb, depth = self._sensed[1], self._sensed[2]
        believed = self.estimate_world
        # exactly (0, 0, 0) at the start (the Backend contract), not 1e-16 from the frame change
        pose = Pose2D() if believed == self.start_pose_world else believed.relative_to(self.start_pose_world)
        if self.frame_origin is not None:
            pose = self.frame_origin.compose(pose)
        return Observation(
            rgb=rgb,
            depth_m=depth,
            pose=pose,
            intrinsics=self.camera.intrinsics,
            goal_image=self.goal_image,
            camera_height_m=self.camera.height_m,
            camera_tilt_rad=self.camera.pitch_rad,
            step=self.steps,
            timestamp_s=time.time(),
        )

    def apply(self, action: Action) -> None:
        if self._closed:
            raise BackendError("closed", "backend is closed")
        if self.done:
            raise BackendError("episode_over", f"the episode ended ({self.stop_reason}); reset() to start again")
        action = Action(action)
        self.steps += 1
        self.actions.append(action)
        if action == Action.STOP:
            self.called_stop = True
            self.done = True
            self.stop_reason = "stop"
        else:
            before = self.pose_world
            if self._noise is None:
                new, moved = self.world.move(before, action)
            else:
                forward_m, lateral_m, turn_rad, slipped = self._noise.actual_motion(action)
                new, moved = self.world.move_by(before, forward_m, lateral_m, turn_rad)
                self._noise.update_estimate(action, before, new, slipped, _commanded(action), self.steps)
            if moved and action == Action.MOVE_FORWARD:
                self.path_length_m += math.hypot(new.x_m - self.pose_world.x_m, new.y_m - self.pose_world.y_m)
            self.pose_world = new
            if self.steps >= self.max_steps:
                self.done = True
                self.stop_reason = "max_steps"
        self.trajectory_world.append(self.pose_world)
        self.estimate_trajectory_world.append(self.estimate_world)

    @property
    def estimate_world(self) -> Pose2D:
        """The pose the agent believes it has (world frame); the true pose without pose noise."""
        if self._noise is None or self._noise.estimate_world is None:
            return self.pose_world
        return self._noise.estimate_world

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            if self.owns_world:
                self.world.close()

    # --- scoring ---
    def goal_field(self) -> np.ndarray | None:
        if self.goal_instance_id is None or len(self.viewpoints_world) == 0:  # resolves the scoring data
            return None
        if self._field is None:
            grid = self.world.navigable_grid(GRID_RESOLUTION_M)
            self._field = geodesic_field(grid, self.viewpoints_world)
        return self._field

    @property
    def shortest_path_m(self) -> float:
        if self._shortest_path_m is None:
            self._shortest_path_m = self.oracle.geodesic_to_goal_m(self.start_pose_world.x_m, self.start_pose_world.y_m)
        return self._shortest_path_m

    def result(self) -> EpisodeMetrics | None:
        """The episode's metrics once it is over; None if unscored or still running."""
        if self.goal_instance_id is None or not self.done:
            return None
        p = self.pose_world
        return episode_metrics(
            called_stop=self.called_stop,
            stop_xy_m=(p.x_m, p.y_m),
            viewpoints_xy_m=self.viewpoints_world,
            steps=self.steps,
            max_steps=self.max_steps,
            path_length_m=self.path_length_m,
            shortest_path_m=self.shortest_path_m,
            stop_geodesic_m=self.oracle.geodesic_to_goal_m(p.x_m, p.y_m),
        )
