"""Pictures for people: a home's top-down map (rooms, labelled instances, an episode's
start and viewpoints, an agent's path) and a sheet of goal images. Pure drawing
(OpenCV) on the spec; no PyBullet."""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

import cv2
import numpy as np

from sim.geometry import Footprint, FootprintIndex, RectFootprint
from sim.home import HomeSpec

_ROOM_COLOURS = {
    "living room": (232, 222, 200),
    "kitchen": (214, 232, 210),
    "bedroom": (210, 220, 238),
    "bathroom": (236, 214, 226),
    "hallway": (228, 228, 228),
}
_CATEGORY_COLOURS = {
    "chair": (220, 120, 40),
    "couch": (170, 60, 170),
    "bed": (60, 90, 200),
    "toilet": (40, 170, 190),
    "potted plant": (40, 150, 60),
    "tv": (30, 30, 30),
}


class TopDown:
    """A canvas in the home's world frame: ``px(x, y)`` maps metres to pixels (y up)."""

    def __init__(self, home: HomeSpec, px_per_m: float = 60.0, margin_px: int = 30) -> None:
        self.home, self.s, self.m = home, px_per_m, margin_px
        x0, y0, x1, y1 = home.bounds_m
        self.x0, self.y1 = x0, y1
        self.img = np.full(
            (int((y1 - y0) * px_per_m) + 2 * margin_px, int((x1 - x0) * px_per_m) + 2 * margin_px, 3), 255, np.uint8
        )

    def px(self, x_m: float, y_m: float) -> tuple[int, int]:
        return (int(round(self.m + (x_m - self.x0) * self.s)), int(round(self.m + (self.y1 - y_m) * self.s)))

    def poly(self, xy: np.ndarray) -> np.ndarray:
        return np.array([self.px(x, y) for x, y in xy], np.int32).reshape(-1, 1, 2)

    def _fill(self, fp: Footprint, colour: tuple[int, int, int]) -> None:
        if isinstance(fp, RectFootprint):
            cv2.fillPoly(self.img, [self.poly(fp.corners_xy())], colour)
        else:
            cv2.circle(self.img, self.px(fp.cx_m, fp.cy_m), max(1, int(fp.r_m * self.s)), colour, -1)

    def draw_home(self, navigable: bool = True, labels: bool = True) -> TopDown:
        home = self.home
        for room in home.rooms:
            x0, y0, x1, y1 = room.rect_m
            cv2.rectangle(self.img, self.px(x0, y1), self.px(x1, y0), _ROOM_COLOURS.get(room.kind, (230, 230, 230)), -1)
        if navigable:
            grid = FootprintIndex(home.solid_footprints(), home.bounds_m).navigable_grid(0.05)
            xs, ys = grid.cell_centres()
            for i, j in np.argwhere(~grid.navigable & (xs > home.bounds_m[0]) & (xs < home.bounds_m[2])):
                p = self.px(xs[i, j], ys[i, j])
                self.img[p[1], p[0]] = (self.img[p[1], p[0]] * 0.82).astype(np.uint8)
        for obj in home.objects:  # floor coverings first, so furniture stays on top
            for part in obj.parts:
                if not part.solid:
                    self._fill(part.footprint(), (215, 205, 190))
        for obj in home.objects:
            col = _CATEGORY_COLOURS.get(obj.category, (150, 150, 150)) if obj.is_instance else (185, 185, 185)
            for part in obj.parts:
                if part.solid:
                    self._fill(part.footprint(), col)
        for w in home.walls:
            if w.center_xyz_m[2] - w.size_xyz_m[2] / 2 > 0.5:
                continue  # lintels over doorways
            self._fill(w.footprint(), (60, 60, 60))
        if labels:
            for room in home.rooms:
                x0, y0, x1, y1 = room.rect_m
                self.text(room.name, (x0 + 0.1, y1 - 0.25), (90, 90, 90), 0.45)
            for obj in home.instances:
                cx, cy, _ = obj.center_xyz_m()
                self.text(f"{obj.object_id}:{obj.category}", (cx - 0.3, cy), (0, 0, 0), 0.38)
        return self

    def text(self, s: str, xy_m: tuple[float, float], colour=(0, 0, 0), scale: float = 0.4) -> None:
        p = self.px(*xy_m)
        cv2.putText(self.img, s, p, cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), 3, cv2.LINE_AA)
        cv2.putText(self.img, s, p, cv2.FONT_HERSHEY_SIMPLEX, scale, colour, 1, cv2.LINE_AA)

    def draw_points(self, xy_m: np.ndarray, colour=(0, 200, 0), radius_px: int = 2) -> TopDown:
        for x, y in np.asarray(xy_m).reshape(-1, 2):
            cv2.circle(self.img, self.px(x, y), radius_px, colour, -1)
        return self

    def draw_pose(
        self, x_m: float, y_m: float, yaw_rad: float, colour=(220, 0, 0), label: str | None = None
    ) -> TopDown:
        cv2.circle(self.img, self.px(x_m, y_m), max(3, int(0.17 * self.s)), colour, 2)
        tip = (x_m + 0.35 * math.cos(yaw_rad), y_m + 0.35 * math.sin(yaw_rad))
        cv2.arrowedLine(self.img, self.px(x_m, y_m), self.px(*tip), colour, 2, tipLength=0.4)
        if label:
            self.text(label, (x_m + 0.2, y_m + 0.2), colour, 0.45)
        return self

    def draw_path(self, poses_xy: Sequence[Sequence[float]], colour=(0, 90, 230)) -> TopDown:
        pts = np.array([self.px(p[0], p[1]) for p in poses_xy], np.int32).reshape(-1, 1, 2)
        if len(pts) > 1:
            cv2.polylines(self.img, [pts], False, colour, 2, cv2.LINE_AA)
        return self

    def rgb(self) -> np.ndarray:
        return self.img


def goal_sheet(images: Iterable[tuple[str, np.ndarray]], columns: int = 5, tile_px: int = 220) -> np.ndarray:
    """A grid of (caption, RGB image) tiles."""
    tiles = []
    for caption, img in images:
        t = cv2.resize(img, (tile_px, tile_px), interpolation=cv2.INTER_AREA).copy()
        cv2.rectangle(t, (0, 0), (tile_px, 16), (0, 0, 0), -1)
        cv2.putText(t, caption[:34], (3, 12), cv2.FONT_HERSHEY_SIMPLEX, 0.38, (255, 255, 255), 1, cv2.LINE_AA)
        tiles.append(t)
    if not tiles:
        return np.full((tile_px, tile_px, 3), 255, np.uint8)
    while len(tiles) % columns:
        tiles.append(np.full_like(tiles[0], 255))
    return np.vstack([np.hstack(tiles[i : i + columns]) for i in range(0, len(tiles), columns)])
