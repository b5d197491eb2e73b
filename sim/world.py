"""``SimWorld``: a procedural home built in PyBullet (DIRECT mode, CPU TinyRenderer).

Public contract (CONTRIBUTING.md):

* ``SimWorld.from_seed(scene_seed)`` / ``SimWorld(home_spec)``; ``.home`` is the ``HomeSpec``.
* ``.render(pose_world, camera=SIM_CAMERA) -> Render(rgb, depth_m, instance_ids)``: the
  robot's camera at a floor pose (camera height and pitch from the spec).
  ``.render_view(eye_xyz, yaw, pitch, camera)`` renders any camera (goal images).
* ``.move(pose_world, action) -> (pose_world, moved)``: one discrete action of docs/architecture.md
  section 1 (forward 0.25 m, turns 30 deg). A forward move whose swept path collides
  leaves the pose unchanged (no sliding); ``moved`` is False then and for STOP.
* ``.collides(x_m, y_m)``: the robot cylinder (r 0.17 m, h 1.41 m) at that position
  overlaps the scene (walls, furniture; rugs are drivable) or leaves the home.
* ``.navigable_grid(resolution_m)``: ground-truth ``NavGrid`` (world frame), cached.
* ``.ray_objects(from_xyz, to_xyz)``: first object hit along rays (visibility tests).
* ``.close()``: idempotent.

A render draws only the rooms the camera can see (``sim.visibility``) and is reused when the
same frame is asked for again (issue 32): the frame is a pure function of what PyBullet is
given (the view and projection matrices, in float32 once they reach it, the image size and
the set of bodies shown), so the last ``reuse_frames`` frames are kept under that key and a
camera back at one of them gets a copy (an agent turning to and fro, or back where it was,
asks for about 9% of its frames again in the recorded train10 runs). The segmentation buffer comes out of the same
TinyRenderer pass at no measurable cost (it is rasterised whether asked for or not; leaving
it out with ``ER_NO_SEGMENTATION_MASK`` only skips a copy), so it is always kept.

Every furniture piece is one multi-link body: one link per material with a
world-UV mesh (no collision), one collision-only link per convex part (for ray
tests). Its segmentation id is therefore one id per instance.
"""

from __future__ import annotations

import logging
import math
import time
from collections import OrderedDict, defaultdict

import numpy as np
import pybullet as pb

from agent.types import FORWARD_STEP_M, TURN_ANGLE_DEG, Action, Pose2D, wrap_angle
from sim import meshes
from sim.camera import SIM_CAMERA, CameraSpec, Render, camera_axes, depth_buffer_to_metres, rgba_to_rgb
from sim.geometry import FootprintIndex, NavGrid
from sim.home import FOLIAGE_JITTER, HomeSpec, Part, SceneObject
from sim.scene_gen import generate_home
from sim.textures import texture_path
from sim.visibility import ViewCuller

log = logging.getLogger(__name__)

# sub-steps of a forward move checked for collision (no tunnelling past corners)
_SWEEP_SAMPLES = 5
_LIGHT = dict(
    lightDirection=[0.4, 0.25, 1.0],
    lightColor=[1.0, 1.0, 1.0],
    lightDistance=10.0,
    lightAmbientCoeff=0.55,
    lightDiffuseCoeff=0.5,
    lightSpecularCoeff=0.02,
)
# frames kept for a camera that comes back (about 2.5 MB each at 360 x 640): in recorded agent
# runs the share of frames found again grows up to 16 kept frames and no further
REUSE_FRAMES = 16


def _part_mesh(part: Part, tile_m: float) -> meshes.Mesh:
    if part.shape == "box":
        # shift the pattern per part so that, say, four chair legs do not show the same patch
        cx, cy, cz = part.center_xyz_m
        offset = ((cx * 3.7 + cy * 1.9) % 1.0 * tile_m, (cz * 2.3 + cy * 3.1) % 1.0 * tile_m)
        local = meshes.box(part.size_xyz_m, tile_m, part.uv_mode, offset)
    elif part.shape == "cylinder":
        local = meshes.cylinder(part.size_xyz_m[0] / 2.0, part.size_xyz_m[2], tile_m, part.taper)
    elif part.shape == "ellipsoid":
        # lumpy foliage: deterministic jitter from the part's position
        seed = sum(int(round(v * 1000.0)) * k for v, k in zip(part.center_xyz_m, (73856093, 19349663, 83492791))) % (
            2**31
        )
        rng = np.random.default_rng([seed, 11])
        jitter = rng.uniform(2.0 - FOLIAGE_JITTER, FOLIAGE_JITTER, (7, 10))
        jitter[0] = jitter[0].mean()
        jitter[-1] = jitter[-1].mean()
        radii = tuple(s / 2.0 for s in part.size_xyz_m)
        local = meshes.ellipsoid(radii, tile_m, rings=6, segments=10, jitter=jitter)  # type: ignore[arg-type]
    else:
        raise ValueError(f"unknown part shape {part.shape!r}")
    return local.transformed(part.center_xyz_m, part.yaw_rad)


class SimWorld:
    """A built home. Not thread-safe; one PyBullet client per world."""

    def __init__(self, home: HomeSpec, cull: bool = True, reuse_frames: int = REUSE_FRAMES) -> None:
        """cull: skip drawing rooms the camera cannot see (identical images, faster renders).
        reuse_frames: how many recent frames to keep for a camera that comes back (0: none)."""
        t0 = time.perf_counter()
        self.home = home
        self._client = pb.connect(pb.DIRECT)  # visual meshes: rendering
        self._ray_client = pb.connect(pb.DIRECT)  # collision shapes: ray tests
        self._ray_body_to_object: dict[int, int] = {}
        self.cull = cull
        self._cull_groups: list[tuple[frozenset[int], int]] = []
        self._links: dict[int, int] = {}
        self._shown: dict[int, bool] = {}
        self._culler: ViewCuller | None = None
        self.reuse_frames = reuse_frames
        # (camera, view matrix, visible rooms) -> the frame, read-only, most recent last
        self._frames: OrderedDict[tuple, Render] = OrderedDict()
        self._projections: dict[CameraSpec, tuple[float, ...]] = {}
        self.frames_reused = 0
        self._textures: dict[str, int] = {}
        self.body_to_object: dict[int, int] = {}
        self.object_to_body: dict[int, int] = {}
        self._grids: dict[float, NavGrid] = {}
        x0, y0, x1, y1 = home.bounds_m
        self.footprints = FootprintIndex(home.solid_footprints(), (x0, y0, x1, y1))
        try:
            self._build()
        except BaseException:
            self.close()  # do not leak the PyBullet clients
            raise
        n_bodies = pb.getNumBodies(physicsClientId=self._client)
        self._seg_lut = np.full(n_bodies + 2, -1, dtype=np.int32)
        for body, obj in self.body_to_object.items():
            if home.objects[obj].is_instance:
                self._seg_lut[body + 1] = obj
        log.debug(
            "built home %d: %d bodies, %d textures in %.2f s",
            home.seed,
            n_bodies,
            len(self._textures),
            time.perf_counter() - t0,
        )

    @classmethod
    def from_seed(cls, scene_seed: int) -> SimWorld:
        return cls(generate_home(scene_seed))

    # --- building ------------------------------------------------------------

    def _texture(self, key: str) -> int:
        if key not in self._textures:
            self._textures[key] = pb.loadTexture(
                str(texture_path(self.home.materials[key])), physicsClientId=self._client
            )
        return self._textures[key]

    def _multibody(self, client: int, links: list[tuple[int, int]]) -> int:
        """A static body at the origin with one fixed link per (visual, collision) shape pair."""
        n = len(links)
        return pb.createMultiBody(
            baseMass=0,
            baseCollisionShapeIndex=-1,
            baseVisualShapeIndex=-1,
            basePosition=[0, 0, 0],
            linkMasses=[0] * n,
            linkCollisionShapeIndices=[s for _, s in links],
            linkVisualShapeIndices=[v for v, _ in links],
            linkPositions=[[0, 0, 0]] * n,
            linkOrientations=[[0, 0, 0, 1]] * n,
            linkInertialFramePositions=[[0, 0, 0]] * n,
            linkInertialFrameOrientations=[[0, 0, 0, 1]] * n,
            linkParentIndices=[0] * n,
            linkJointTypes=[pb.JOINT_FIXED] * n,
            linkJointAxis=[[0, 0, 1]] * n,
            physicsClientId=client,
        )

    def _body(self, parts: tuple[Part, ...] | list[Part], collide: bool = True) -> tuple[int, int]:
        """(render body, ray body or -1). Visual meshes and collision shapes live in separate
        clients: TinyRenderer draws a link's collision shape when the link has no visual
        shape, which z-fights with the textured meshes (stripes, white patches)."""
        c = self._client
        by_material: dict[str, list[Part]] = defaultdict(list)
        for p in parts:
            by_material[p.material].append(p)
        vis = []
        for key, group in by_material.items():
            mesh = meshes.Mesh.merge([_part_mesh(p, self.home.materials[key].tile_m) for p in group])
            vis.append(
                (
                    key,
                    pb.createVisualShape(
                        pb.GEOM_MESH,
                        vertices=mesh.vertices.tolist(),
                        indices=mesh.indices.tolist(),
                        uvs=mesh.uvs.tolist(),
                        normals=mesh.normals.tolist(),
                        physicsClientId=c,
                    ),
                )
            )
        body = self._multibody(c, [(v, -1) for _, v in vis])
        self._links[body] = len(vis)
        for link, (key, _) in enumerate(vis):
            pb.changeVisualShape(
                body, link, textureUniqueId=self._textures[key], rgbaColor=[1, 1, 1, 1], physicsClientId=c
            )
        if not collide:
            return body, -1
        rc = self._ray_client
        col = []
        for p in parts:
            if p.shape == "box":
                col.append(
                    pb.createCollisionShape(
                        pb.GEOM_BOX,
                        halfExtents=[s / 2.0 for s in p.size_xyz_m],
                        collisionFramePosition=p.center_xyz_m,
                        collisionFrameOrientation=pb.getQuaternionFromEuler([0, 0, p.yaw_rad]),
                        physicsClientId=rc,
                    )
                )
            else:  # convex hull of the visual mesh
                col.append(
                    pb.createCollisionShape(
                        pb.GEOM_MESH, vertices=_part_mesh(p, 1.0).vertices.tolist(), physicsClientId=rc
                    )
                )
        return body, self._multibody(rc, [(-1, s) for s in col])

    def _build(self) -> None:
        home = self.home
        for key in sorted(home.materials):
            self._texture(key)
        # Architecture is split by room so that rooms a camera cannot see can be skipped
        # (sim.visibility): walls grouped by the rooms they bound, floor and ceiling per room.
        by_rooms: dict[frozenset[int], list[Part]] = defaultdict(list)
        for w in home.walls:
            x0, y0, x1, y1 = w.footprint().bounds()
            touching = frozenset(
                r.index
                for r in home.rooms
                if x0 <= r.rect_m[2] + 1e-6
                and r.rect_m[0] <= x1 + 1e-6
                and y0 <= r.rect_m[3] + 1e-6
                and r.rect_m[1] <= y1 + 1e-6
            )
            by_rooms[touching].append(w)
        for rooms, parts in sorted(by_rooms.items(), key=lambda kv: sorted(kv[0])):
            self._cull_groups.append((rooms, self._body(parts)[0]))
        floors: dict[int, list[Part]] = defaultdict(list)
        for f in home.floors:
            room = home.room_at(f.center_xyz_m[0], f.center_xyz_m[1])
            floors[room.index if room else -1].append(f)
        for ri, parts in sorted(floors.items()):
            self._cull_groups.append((frozenset([ri]) if ri >= 0 else frozenset(), self._body(parts)[0]))
        c = home.ceiling
        for room in home.rooms:
            x0, y0, x1, y1 = room.rect_m
            part = Part(
                "box",
                ((x0 + x1) / 2, (y0 + y1) / 2, c.center_xyz_m[2]),
                (x1 - x0, y1 - y0, c.size_xyz_m[2]),
                0.0,
                c.material,
                solid=False,
            )
            self._cull_groups.append((frozenset([room.index]), self._body([part], collide=False)[0]))
        for obj in home.objects:
            body, ray_body = self._body(obj.parts)
            self.body_to_object[body] = obj.object_id
            self.object_to_body[obj.object_id] = body
            self._ray_body_to_object[ray_body] = obj.object_id
            self._cull_groups.append((frozenset([obj.room_index]), body))

    def _visible(
        self, eye_xy: tuple[float, float], yaw_rad: float, pitch_rad: float, camera: CameraSpec
    ) -> frozenset[int] | None:
        """The rooms the camera can see (``sim.visibility``); None: draw everything (culling
        off, or the camera outside every room)."""
        if not self.cull:
            return None
        if self._culler is None:
            self._culler = ViewCuller(self.home)
        visible = self._culler.visible_rooms(
            eye_xy, yaw_rad, pitch_rad, camera.hfov_deg, camera.vfov_deg, camera.width_px
        )
        return frozenset(visible) if visible else None

    def _show(self, visible: frozenset[int] | None) -> None:
        """Hide the bodies of rooms outside ``visible``, show the others: TinyRenderer
        rasterises every front-facing triangle in view, hidden or not."""
        for rooms, body in self._cull_groups:
            show = visible is None or not rooms or bool(rooms & visible)
            if self._shown.get(body, True) != show:
                for link in range(self._links[body]):
                    pb.changeVisualShape(
                        body, link, rgbaColor=[1, 1, 1, 1 if show else 0], physicsClientId=self._client
                    )
                self._shown[body] = show

    def _projection(self, camera: CameraSpec) -> tuple[float, ...]:
        """PyBullet's projection matrix of a camera (the same every frame: computed once)."""
        proj = self._projections.get(camera)
        if proj is None:
            proj = tuple(
                pb.computeProjectionMatrixFOV(
                    camera.vfov_deg,
                    camera.width_px / camera.height_px,
                    camera.near_m,
                    camera.far_m,
                    physicsClientId=self._client,
                )
            )
            self._projections[camera] = proj
        return proj

    def _view(self, eye: np.ndarray, yaw_rad: float, pitch_rad: float) -> tuple[float, ...]:
        """PyBullet's view matrix (float32 values: what the renderer is given)."""
        forward, up = camera_axes(yaw_rad, pitch_rad)
        return tuple(
            pb.computeViewMatrix(eye.tolist(), (eye + forward).tolist(), up.tolist(), physicsClientId=self._client)
        )

    def _raster(self, camera: CameraSpec, view: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """TinyRenderer's buffers: (H, W, 4) uint8 RGBA, (H, W) float32 depth buffer, (H, W)
        int32 body ids."""
        w, h, rgba, depth, seg = pb.getCameraImage(
            camera.width_px,
            camera.height_px,
            list(view),
            list(self._projection(camera)),
            renderer=pb.ER_TINY_RENDERER,
            shadow=0,
            physicsClientId=self._client,
            **_LIGHT,
        )
        return (
            np.asarray(rgba, dtype=np.uint8).reshape(h, w, 4),
            np.asarray(depth, dtype=np.float32).reshape(h, w),
            np.asarray(seg).reshape(h, w),
        )

    # --- queries ---------------------------------------------------------------

    def collides(self, x_m: float, y_m: float) -> bool:
        return self.footprints.collides(x_m, y_m)

    def move(self, pose_world: Pose2D, action: Action) -> tuple[Pose2D, bool]:
        """The exact motion model: 0.25 m forward (blocked as a whole by a collision), 30 deg turns."""
        if action == Action.MOVE_FORWARD:
            return self.move_by(pose_world, FORWARD_STEP_M)
        if action == Action.TURN_LEFT:
            return self.move_by(pose_world, 0.0, turn_rad=math.radians(TURN_ANGLE_DEG))
        if action == Action.TURN_RIGHT:
            return self.move_by(pose_world, 0.0, turn_rad=-math.radians(TURN_ANGLE_DEG))
        if action == Action.STOP:
            return pose_world, False
        raise ValueError(f"unknown action {action!r}")

    def move_by(
        self, pose_world: Pose2D, forward_m: float, lateral_m: float = 0.0, turn_rad: float = 0.0
    ) -> tuple[Pose2D, bool]:
        """A move of any size (the realism profiles' actuation): a translation in the robot's
        frame, swept for collisions (a collision anywhere blocks the whole move, as the exact
        model's), then a turn in place. Returns (new pose, moved)."""
        if forward_m == 0.0 and lateral_m == 0.0:
            if turn_rad == 0.0:
                return pose_world, False
            return Pose2D(pose_world.x_m, pose_world.y_m, wrap_angle(pose_world.yaw_rad + turn_rad)), True
        c, s = math.cos(pose_world.yaw_rad), math.sin(pose_world.yaw_rad)
        dx = forward_m * c - lateral_m * s
        dy = forward_m * s + lateral_m * c
        for k in range(1, _SWEEP_SAMPLES + 1):
            t = k / _SWEEP_SAMPLES
            if self.collides(pose_world.x_m + t * dx, pose_world.y_m + t * dy):
                return pose_world, False
        yaw = pose_world.yaw_rad if turn_rad == 0.0 else wrap_angle(pose_world.yaw_rad + turn_rad)
        return Pose2D(pose_world.x_m + dx, pose_world.y_m + dy, yaw), True

    def navigable_grid(self, resolution_m: float = 0.05) -> NavGrid:
        key = round(resolution_m, 6)
        if key not in self._grids:
            self._grids[key] = self.footprints.navigable_grid(resolution_m)
        return self._grids[key]

    def instance(self, instance_id: int) -> SceneObject:
        return self.home.instance(instance_id)

    def ray_objects(self, from_xyz: np.ndarray, to_xyz: np.ndarray) -> np.ndarray:
        """First object hit along each ray: (N,) int64 object id, -1 for walls/floors, -2 for no hit."""
        from_xyz = np.asarray(from_xyz, dtype=np.float64).reshape(-1, 3)
        to_xyz = np.asarray(to_xyz, dtype=np.float64).reshape(-1, 3)
        out = np.empty(len(from_xyz), dtype=np.int64)
        batch = pb.MAX_RAY_INTERSECTION_BATCH_SIZE - 1
        for s in range(0, len(from_xyz), batch):
            hits = pb.rayTestBatch(
                from_xyz[s : s + batch].tolist(), to_xyz[s : s + batch].tolist(), physicsClientId=self._ray_client
            )
            for k, h in enumerate(hits):
                out[s + k] = -2 if h[0] < 0 else self._ray_body_to_object.get(h[0], -1)
        return out

    # --- rendering -------------------------------------------------------------

    def render_view(
        self, eye_xyz: tuple[float, float, float] | np.ndarray, yaw_rad: float, pitch_rad: float, camera: CameraSpec
    ) -> Render:
        """Render from any camera pose (yaw CCW from +x, pitch positive down). The arrays are
        the caller's own."""
        eye = np.asarray(eye_xyz, dtype=np.float64)
        visible = self._visible((float(eye[0]), float(eye[1])), yaw_rad, pitch_rad, camera)
        view = self._view(eye, yaw_rad, pitch_rad)
        key = (camera, view, visible)
        kept = self._frames.get(key)
        if kept is not None:
            self._frames.move_to_end(key)
            self.frames_reused += 1
            return kept.copy()
        self._show(visible)
        rgba, depth_buf, seg = self._raster(camera, view)
        frame = Render(
            rgba_to_rgb(rgba), depth_buffer_to_metres(depth_buf, camera.near_m, camera.far_m), seg, self._seg_lut
        )
        if self.reuse_frames > 0:
            kept = frame.copy()
            for a in (kept.rgb, kept.depth_m, kept.seg_raw):
                a.flags.writeable = False
            self._frames[key] = kept
            while len(self._frames) > self.reuse_frames:
                self._frames.popitem(last=False)
        return frame

    def render(self, pose_world: Pose2D, camera: CameraSpec = SIM_CAMERA) -> Render:
        """The robot's camera at a floor pose."""
        eye = (pose_world.x_m, pose_world.y_m, camera.height_m)
        return self.render_view(eye, pose_world.yaw_rad, camera.pitch_rad, camera)

    def close(self) -> None:
        self._frames.clear()
        for name in ("_client", "_ray_client"):
            client = getattr(self, name, -1)
            if client is not None and client >= 0:
                try:
                    pb.disconnect(physicsClientId=client)
                except pb.error as exc:  # already disconnected: nothing left to release
                    log.debug("disconnect: %s", exc)
                setattr(self, name, -1)

    def __enter__(self) -> SimWorld:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
