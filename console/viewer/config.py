"""The viewer's settings (``console.viewer``)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class ViewerConfig:
    host: str = "127.0.0.1"
    port: int = 0  # 0: any free port (viser would silently take the next one if busy anyway)
    map_hz: float = 1.5  # docs/architecture.md section 5: map at 1-2 Hz
    pose_hz: float = 10.0  # pose and images at up to 10 Hz
    image_height_px: int = 240  # GUI images are downscaled to this height before sending
    max_obstacle_points: int = 30_000
