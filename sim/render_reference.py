"""The robot camera's render as it was before issue 32, kept as a reference.

``SimWorld.render_view`` now reuses frames and buffers and converts depth in place; this is the
plain render it replaced (matrices every frame, a strided RGB copy, depth through temporaries).
The render test asserts that both give the very same frames, and ``benchmarks/bench_sim.py
--issue32`` times one against the other.
"""

from __future__ import annotations

import numpy as np
import pybullet as pb

from sim.camera import CameraSpec, camera_axes
from sim.world import _LIGHT, SimWorld


def depth_plain(buf: np.ndarray, near_m: float, far_m: float) -> np.ndarray:
    """OpenGL depth buffer -> metres, as ``depth_buffer_to_metres`` did before issue 32."""
    buf = np.asarray(buf, dtype=np.float64)
    depth = far_m * near_m / (far_m - (far_m - near_m) * buf)
    depth[buf >= 1.0 - 1e-7] = 0.0
    return depth.astype(np.float32)


def render_plain(
    world: SimWorld, eye_xyz: tuple | np.ndarray, yaw_rad: float, pitch_rad: float, camera: CameraSpec
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rgb, depth_m, raw segmentation) of one view, rendered as before issue 32."""
    eye = np.asarray(eye_xyz, dtype=np.float64)
    world._show(world._visible((float(eye[0]), float(eye[1])), yaw_rad, pitch_rad, camera))
    forward, up = camera_axes(yaw_rad, pitch_rad)
    client = world._client
    view = pb.computeViewMatrix(eye.tolist(), (eye + forward).tolist(), up.tolist(), physicsClientId=client)
    proj = pb.computeProjectionMatrixFOV(
        camera.vfov_deg, camera.width_px / camera.height_px, camera.near_m, camera.far_m, physicsClientId=client
    )
    w, h, rgba, depth, seg = pb.getCameraImage(
        camera.width_px,
        camera.height_px,
        view,
        proj,
        renderer=pb.ER_TINY_RENDERER,
        shadow=0,
        physicsClientId=client,
        **_LIGHT,
    )
    rgb = np.asarray(rgba, dtype=np.uint8).reshape(h, w, 4)[:, :, :3].copy()
    depth_m = depth_plain(np.asarray(depth, dtype=np.float32).reshape(h, w), camera.near_m, camera.far_m)
    return rgb, depth_m, np.asarray(seg).reshape(h, w)
