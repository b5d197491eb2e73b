"""The live 3D view: a viser server showing the active run (read-only, plus a stop button).

Scene (the run's start-relative frame, z up, metres):
  /map/occupancy   the agent's map layers as a textured floor plane (unknown cells transparent):
                   explored, visited, obstacles, frontiers, collisions, goal cells
  /map/obstacles   obstacle cells as a point cloud (a few heights, so walls read as walls)
  /goal/points     projected goal points (red)
  /plan            planned path (yellow) and /target the frontier or goal target (magenta)
  /trajectory      the path driven so far (green)
  /robot           the robot body (cylinder) and /robot_camera a frustum textured with the live RGB
GUI: status, stop button (asks for the token when the console requires one), live RGB,
depth, goal photo, keypoint matches, and re-ID score against tau over the steps.

Security. viser's GUI state is shared by every client unless it is created per client,
so the stop control (token box, button, note) is built for each client in its
``on_client_connect`` handler: a token typed by one client is never sent to another,
the box is masked and cleared after each use. The websocket handshake is checked like
the API's requests (``console.security``): a Host header that is not a name of this
console (DNS rebinding) or an Origin that is not the viewer itself (a page elsewhere
opening a websocket to 127.0.0.1) gets the connection closed before anything is sent.

Publishing never blocks the control loop: the worker thread only ``offer``s its
latest ``StepRecord``; this module's thread takes the newest one at most
``pose_hz`` times a second (pose, images) and redraws the map at most ``map_hz``.
Records in between are skipped, which is the point.
"""

from __future__ import annotations

import hmac
import logging
import math
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from console.pictures import depth_rgb, fit_height, layers_rgb, match_picture
from console.scene_geometry import camera_rotation, rotation_to_wxyz, segments, set_segments
from console.security import LOOPBACK_NAMES, host_allowed, origin_allowed
from console.words import step_words
from agent.types import Pose2D
from console.session import Outcome, StepRecord

logger = logging.getLogger(__name__)


CANDIDATE_RGB = {"potential": (255, 140, 0), "confirmed": (0, 180, 80), "rejected": (154, 90, 190)}


@dataclass(frozen=True, slots=True)
class ViewerConfig:
    host: str = "127.0.0.1"
    port: int = 0  # 0: any free port (viser would silently take the next one if busy anyway)
    map_hz: float = 1.5  # DESIGN section 5: map at 1-2 Hz
    pose_hz: float = 10.0  # pose and images at up to 10 Hz
    image_height_px: int = 240  # GUI images are downscaled to this height before sending
    max_obstacle_points: int = 30_000


@dataclass(slots=True)
class _ClientControls:
    """One browser's own stop control (never shared with other clients)."""

    token_box: Any | None
    stop_button: Any
    note: Any


class Viewer:
    """Owns the viser server and its publishing thread."""

    def __init__(
        self,
        config: ViewerConfig = ViewerConfig(),
        on_stop: Callable[[], str] | None = None,
        token: str | None = None,
        allowed_hosts: Sequence[str] = LOOPBACK_NAMES,
    ) -> None:
        import viser  # heavy import, only when a viewer is wanted

        self.config = config
        self._on_stop = on_stop
        self._token = token
        self._allowed_hosts = tuple(allowed_hosts)
        self.n_rejected = 0
        self.server = viser.ViserServer(host=config.host, port=config.port, label="imgnav", verbose=False)
        # Before any client can have finished its handshake: reject foreign Host/Origin.
        self.server._websock_server.on_client_connect(self._check_handshake)
        # The share button asks an outside service for a public tunnel: never offer it.
        self.server.gui.configure_theme(show_share_button=False, show_logo=False, control_width="large")
        self.server.scene.set_up_direction("+z")
        # Look down on the start area from behind and above (a home is ~5-10 m across).
        self.server.initial_camera.position = (-4.0, -4.0, 7.0)
        self.server.initial_camera.look_at = (1.5, 1.5, 0.0)
        self._lock = threading.Lock()
        self._wake = threading.Condition(self._lock)
        # viser handles are touched by the run manager's worker (run_started/run_ended), this
        # module's publishing thread and viser's own threads (clicks): one lock for all of them.
        self._handles_lock = threading.RLock()
        self._controls: dict[int, _ClientControls] = {}
        self._run_active = False
        self._replay: dict[str, Any] | None = None  # the finished run shown step by step, if any
        self._replay_folder: Any = None
        self.replay_step: int | None = None
        self._latest: StepRecord | None = None
        self._pending_map = False
        self._closed = False
        self._run_id: str | None = None
        self._last_pose_s = 0.0
        self._last_map_s = 0.0
        self.n_published = 0
        self.last_published_step: int | None = None
        self._build_scene()
        self._build_gui()
        self.server.on_client_connect(self._client_connected)
        self.server.on_client_disconnect(self._client_disconnected)
        self._thread = threading.Thread(target=self._loop, name="viewer", daemon=True)
        self._thread.start()
        logger.info("viewer (viser) on port %d", self.port)

    @property
    def port(self) -> int:
        return int(self.server.get_port())

    # --- layout ------------------------------------------------------------

    def _build_scene(self) -> None:
        scene = self.server.scene
        scene.add_grid("/grid", width=20.0, height=20.0, cell_size=1.0, position=(0.0, 0.0, -0.01))
        self._robot = scene.add_cylinder(
            "/robot", radius=0.17, height=1.41, color=(40, 100, 230), position=(0.0, 0.0, 0.705), visible=False
        )
        self._frustum = scene.add_camera_frustum(
            "/robot_camera", fov=math.radians(68.6), aspect=360 / 640, scale=0.35, color=(40, 100, 230), visible=False
        )
        self._trajectory = None
        self._plan = None
        self._goal_points = None
        self._target = None
        self._occupancy = None
        self._obstacles = None
        self._candidates = None

    def _build_gui(self) -> None:
        gui = self.server.gui
        self._status = gui.add_markdown("**imgnav** - no run yet", order=0.0)
        blank = np.full((8, 8, 3), 200, np.uint8)
        with gui.add_folder("Camera", order=10.0):
            self._rgb_img = gui.add_image(blank, label="egocentric RGB")
            self._depth_img = gui.add_image(blank, label="depth (turbo, 0-5 m)")
        with gui.add_folder("Goal", order=11.0):
            self._goal_img = gui.add_image(blank, label="goal photo")
            self._match_img = gui.add_image(blank, label="keypoint matches (goal | view)")
        with gui.add_folder("Re-identification", order=12.0):
            self._plot = gui.add_uplot(
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

    # --- per-client controls and the handshake check --------------------------

    async def _check_handshake(self, conn: Any) -> None:
        """viser's websocket-level connect hook (awaited before anything is streamed)."""
        ws = self.server._websock_server._live_connections.get(conn.client_id)
        if ws is None:
            return
        headers = ws.request.headers
        host, origin = headers.get("Host"), headers.get("Origin")
        if host_allowed(host, self._allowed_hosts) and origin_allowed(origin, host):
            return
        self.n_rejected += 1
        logger.warning("viewer: refused a connection with Host %r and Origin %r", host, origin)
        await ws.close(1008, "this viewer is not reachable by that name")

    def _client_connected(self, client: Any) -> None:
        gui = client.gui
        token_box = None
        if self._token is not None:
            token_box = gui.add_text("Token", initial_value="", hint="the console's token (asked to stop a run)", order=1.0)
            uuid = getattr(getattr(token_box, "_impl", None), "uuid", None)
            if uuid:  # mask it: viser's text input has no password type
                gui.add_html(
                    f'<style>div:has(> div > p > label[for="{uuid}"]) input '
                    "{ -webkit-text-security: disc; text-security: disc; }</style>",
                    order=1.01,
                )
        with self._handles_lock:
            button = gui.add_button("Stop the run", color="red", disabled=not self._run_active, order=2.0)
            note = gui.add_markdown("", order=3.0)
            controls = _ClientControls(token_box, button, note)
            self._controls[client.client_id] = controls
        button.on_click(lambda _event: self._stop_clicked(controls))

    def _client_disconnected(self, client: Any) -> None:
        with self._handles_lock:
            self._controls.pop(client.client_id, None)

    def _stop_clicked(self, controls: _ClientControls) -> None:
        given = ""
        if controls.token_box is not None:
            given = controls.token_box.value.strip()
            controls.token_box.value = ""  # never left in the box
        if self._token is not None and not hmac.compare_digest(given.encode(), self._token.encode()):
            controls.note.content = "Wrong or missing token: the run goes on."
            return
        message = self._on_stop() if self._on_stop is not None else "no run manager"
        controls.note.content = message

    def _set_stop_enabled(self, enabled: bool) -> None:
        with self._handles_lock:
            self._run_active = enabled
            for controls in self._controls.values():
                controls.stop_button.disabled = not enabled
                if enabled:
                    controls.note.content = ""

    # --- called by the run manager (worker thread): must be cheap ---------------

    def run_started(self, run_id: str, goal_rgb: np.ndarray, info: Mapping[str, Any]) -> None:
        with self._lock:
            self._run_id = run_id
            self._latest = None
        with self._handles_lock:
            self._status.content = f"**Run {run_id}** - starting ({info.get('backend', '')})"
            self._goal_img.image = fit_height(goal_rgb, self.config.image_height_px)
            self._set_stop_enabled(True)
            self._end_replay()
            self._clear_scene()

    def offer(self, rec: StepRecord) -> None:
        with self._wake:
            self._latest = rec
            self._pending_map = True
            self._wake.notify()

    def run_ended(self, run_id: str, status: str, outcome: Outcome) -> None:
        with self._wake:
            latest = self._latest
            self._latest = None
        if latest is not None and latest.run_id == run_id:
            self.publish(latest, with_map=True)  # the final state, whatever the throttle said
        metrics = ""
        if outcome.metrics:
            shown = {k: v for k, v in outcome.metrics.items() if isinstance(v, (int, float, bool))}
            metrics = " - " + ", ".join(f"{k} {v:.3g}" if isinstance(v, float) else f"{k} {v}" for k, v in shown.items())
        with self._handles_lock:
            self._status.content = f"**Run {run_id}** - {status}: **{outcome.outcome}** ({outcome.detail}){metrics}"
            self._set_stop_enabled(False)

    # --- replay of a finished run (console.replay) ------------------------------------------

    def show_replay(
        self,
        store: Any,
        row: Mapping[str, Any],
        steps: list[dict[str, Any]],
        extras: Mapping[int, Mapping[str, Any]],
        step: int,
    ) -> None:
        """Show one step of a finished run: the pose, the trajectory so far, plan, target, goal
        points, the map as the agent knew it then and its camera thumbnail; a "Replay" slider
        (and jumps) in the side panel moves through the run's steps."""
        run_id = row["id"]
        with self._handles_lock:
            if self._replay is None or self._replay["run_id"] != run_id:
                self._clear_scene()
                self._goal_img.image = fit_height(_goal_picture(store, run_id), self.config.image_height_px)
                self._build_replay_gui(store, row, steps, extras)
            slider = self._replay["slider"]
            if int(slider.value) != step + 1:
                slider.value = step + 1  # its callback shows the step
            else:
                self._replay_step(step)

    def _build_replay_gui(self, store: Any, row: Mapping[str, Any], steps: list[dict[str, Any]], extras: Mapping[int, Any]) -> None:
        from console.replay import replay_marks

        if self._replay_folder is not None:
            self._replay_folder.remove()
        marks = replay_marks(steps, dict(extras))
        gui = self.server.gui
        self._replay = {"run_id": row["id"], "store": store, "steps": steps, "extras": extras, "marks": marks, "row": row}
        self._replay_folder = gui.add_folder(f"Replay of run {row['id']}", order=5.0)
        with self._replay_folder:
            slider = gui.add_slider("Step", min=1, max=max(1, len(steps)), step=1, initial_value=1)
            slider.on_update(lambda _e: self._replay_step(int(slider.value) - 1))
            jumps = [("First detection", marks["first_detection"]), ("Stop", marks["stop"] if marks["stop"] is not None else marks["last"])]
            for label, target in jumps:
                button = gui.add_button(label, disabled=target is None)
                if target is not None:
                    button.on_click(lambda _e, t=target: setattr(slider, "value", int(t) + 1))
        self._replay["slider"] = slider

    def _replay_step(self, step: int) -> None:
        from agent.types import CAMERA_HEIGHT_M, SIM_INTRINSICS, Action, AgentRecord, CandidateInfo
        from console.replay import decode_map
        from console.words import step_words

        rp = self._replay
        if rp is None:
            return
        steps = rp["steps"]
        step = max(0, min(step, len(steps) - 1))
        me = steps[step]
        ex = rp["extras"].get(me["step"], {})
        found = rp["store"].replay_map_at(rp["run_id"], me["step"])
        snapshot = decode_map(found[1]) if found is not None else None
        jpeg = rp["store"].replay_frame(rp["run_id"], me["step"])
        rgb = np.asarray(_jpeg_rgb(jpeg)) if jpeg is not None else np.full((64, 36, 3), 200, np.uint8)
        pose = Pose2D(me["x_m"], me["y_m"], me["yaw_rad"] or 0.0)
        record = AgentRecord(
            step=me["step"], action=Action(me["action"]), pose=pose, mode=me["mode"], reason=me["reason"],
            reid_score=me["reid_score"], reid_tau=me["reid_tau"], goal_detected=bool(me["goal_detected"]),
            goal_points_xyz=np.asarray(ex.get("goal_points") or np.zeros((0, 3)), np.float32).reshape(-1, 3),
            target_xy_m=None if ex.get("target") is None else (float(ex["target"][0]), float(ex["target"][1])),
            target_kind=ex.get("target_kind"),
            plan_xy_m=np.asarray(ex.get("plan") or np.zeros((0, 2)), np.float32).reshape(-1, 2),
            map=snapshot,
            candidates=tuple(
                CandidateInfo(c["id"], c["state"], tuple(c["xy_m"]), c["n_views"], c["best_score"], c["distance_m"],
                              c.get("why"))
                for c in ex.get("candidates", [])
            ),
        )
        upto = steps[: step + 1]
        rec = StepRecord(
            run_id=rp["run_id"], step=me["step"], t_s=me["t_s"], action=Action(me["action"]), pose=pose, rgb=rgb,
            depth_m=np.zeros(rgb.shape[:2], np.float32), intrinsics=SIM_INTRINSICS, camera_height_m=CAMERA_HEIGHT_M,
            camera_tilt_rad=0.0, goal_rgb=np.zeros((8, 8, 3), np.uint8), record=record,
            trajectory_xy_m=np.array([[s["x_m"], s["y_m"]] for s in upto], np.float64),
            reid_history=tuple((s["step"], s["reid_score"], s["reid_tau"]) for s in upto),
        )
        with self._handles_lock:
            self._publish_locked(rec, with_map=True, replay=True)
            self._status.content = f"**Replay of run {rp['run_id']}** - {step_words(me)}"
        self.replay_step = me["step"]

    def _clear_scene(self) -> None:
        for handle in (self._trajectory, self._plan, self._goal_points, self._target, self._occupancy, self._obstacles,
                       self._candidates):
            if handle is not None:
                handle.remove()
        self._trajectory = self._plan = self._goal_points = self._target = self._occupancy = self._obstacles = None
        self._candidates = None

    def _end_replay(self) -> None:
        if self._replay_folder is not None:
            self._replay_folder.remove()
        self._replay_folder = None
        self._replay = None

    def close(self) -> None:
        with self._wake:
            self._closed = True
            self._wake.notify()
        self._thread.join(5.0)
        self.server.stop()

    # --- the publishing thread ---------------------------------------------

    def _loop(self) -> None:
        pose_period = 1.0 / self.config.pose_hz
        map_period = 1.0 / self.config.map_hz
        while True:
            with self._wake:
                while self._latest is None and not self._closed:
                    self._wake.wait()
                if self._closed:
                    return
                # Throttle: wait out the pose period. An offer notifies the condition, so the wait
                # repeats until the deadline; newer records replace the pending one meanwhile.
                while True:
                    wait_s = self._last_pose_s + pose_period - time.monotonic()
                    if wait_s <= 0 or self._closed:
                        break
                    self._wake.wait(wait_s)
                if self._closed:
                    return
                rec = self._latest
                self._latest = None
                if rec is None:
                    continue
            now = time.monotonic()
            with_map = now - self._last_map_s >= map_period
            try:
                self.publish(rec, with_map=with_map)
            except Exception:  # the viewer must never take the console down; log and go on
                logger.exception("viewer publishing failed at step %d", rec.step)

    def publish(self, rec: StepRecord, with_map: bool) -> None:
        """Send one step to the browsers (pose, images; the map too if ``with_map``)."""
        with self._handles_lock:
            self._publish_locked(rec, with_map)
        self.n_published += 1
        self.last_published_step = rec.step

    def _publish_locked(self, rec: StepRecord, with_map: bool, replay: bool = False) -> None:
        now = time.monotonic()
        self._last_pose_s = now
        r = rec.record
        scene = self.server.scene
        with self.server.atomic():
            self._publish_pose(rec)
            traj = segments(rec.trajectory_xy_m, 0.03)
            if len(traj):
                if self._trajectory is None:
                    self._trajectory = scene.add_line_segments("/trajectory", traj, (20, 150, 60), thickness=0.04)
                else:
                    set_segments(self._trajectory, traj, (20, 150, 60))
            plan = segments(np.zeros((0, 2)) if r is None else r.plan_xy_m, 0.05)
            if self._plan is None:
                self._plan = scene.add_line_segments(
                    "/plan", plan if len(plan) else np.zeros((1, 2, 3), np.float32), (250, 180, 0), thickness=0.035
                )
            else:
                set_segments(self._plan, plan if len(plan) else np.zeros((1, 2, 3), np.float32), (250, 180, 0))
            if r is not None and r.target_xy_m is not None:
                pos = (float(r.target_xy_m[0]), float(r.target_xy_m[1]), 0.15)
                colour = (230, 30, 40) if r.target_kind == "goal" else (255, 0, 200)
                if self._target is None:
                    self._target = scene.add_icosphere("/target", radius=0.12, color=colour, position=pos)
                else:
                    self._target.position = pos
                    self._target.color = colour
                    self._target.visible = True
            elif self._target is not None:
                self._target.visible = False
            self._publish_candidates(getattr(r, "candidates", ()) if r is not None else ())
            self._publish_images(rec, replay=replay)
            if with_map:
                self._publish_map(rec)

    def _publish_candidates(self, candidates: Any) -> None:
        """Goal candidates as spheres: potential orange, confirmed green, rejected purple."""
        pts = np.array([[c.xy_m[0], c.xy_m[1], 0.35] for c in candidates], np.float32).reshape(-1, 3)
        colours = np.array([CANDIDATE_RGB.get(str(c.state), (200, 200, 200)) for c in candidates], np.uint8).reshape(-1, 3)
        if not len(pts):
            if self._candidates is not None:
                self._candidates.visible = False
            return
        if self._candidates is None:
            self._candidates = self.server.scene.add_point_cloud("/candidates", pts, colours, point_size=0.22, point_shape="circle")
        else:
            self._candidates.points = pts
            self._candidates.colors = colours
            self._candidates.visible = True

    def _publish_pose(self, rec: StepRecord) -> None:
        p = rec.pose
        self._robot.position = (p.x_m, p.y_m, 0.705)
        self._robot.visible = True
        R = camera_rotation(p.yaw_rad, rec.camera_tilt_rad)
        self._frustum.wxyz = rotation_to_wxyz(R)
        self._frustum.position = (p.x_m, p.y_m, rec.camera_height_m)
        self._frustum.fov = math.radians(rec.intrinsics.vfov_deg)
        self._frustum.aspect = rec.intrinsics.width_px / rec.intrinsics.height_px
        self._frustum.image = fit_height(rec.rgb, 160)
        self._frustum.visible = True
        r = rec.record
        # Step numbers count actions from 1, as the pages do.
        self._status.content = f"**Run {rec.run_id}** - " + step_words(
            {
                "step": rec.step,
                "mode": None if r is None else str(r.mode),
                "reason": None if r is None else r.reason,
                "action_name": rec.action.name,
                "reid_score": None if r is None else r.reid_score,
                "reid_tau": None if r is None else r.reid_tau,
            }
        )

    def _publish_images(self, rec: StepRecord, replay: bool = False) -> None:
        h = self.config.image_height_px
        self._rgb_img.image = fit_height(rec.rgb, h)
        if replay:  # a replay keeps the camera thumbnail only (no depth, no matches)
            self._depth_img.image = np.full((8, 8, 3), 200, np.uint8)
            self._match_img.image = np.full((8, 8, 3), 200, np.uint8)
        else:
            self._depth_img.image = fit_height(depth_rgb(rec.depth_m), h)
        r = rec.record
        if r is not None and not replay:
            self._match_img.image = match_picture(rec.goal_rgb, rec.rgb, r.matches_goal_xy, r.matches_obs_xy, height_px=h)
        hist = rec.reid_history
        if hist:
            steps = np.array([s for s, _, _ in hist], np.float64)
            scores = np.array([np.nan if v is None else v for _, v, _ in hist], np.float64)
            taus = np.array([np.nan if t is None else t for _, _, t in hist], np.float64)
            self._plot.data = (steps, scores, taus)

    def _publish_map(self, rec: StepRecord) -> None:
        self._last_map_s = time.monotonic()
        r = rec.record
        scene = self.server.scene
        if r is not None and len(r.goal_points_xyz):
            pts = np.asarray(r.goal_points_xyz, np.float32).reshape(-1, 3)
            if self._goal_points is None:
                self._goal_points = scene.add_point_cloud("/goal/points", pts, (230, 30, 40), point_size=0.06)
            else:
                self._goal_points.points = pts
                self._goal_points.colors = np.tile(np.array([[230, 30, 40]], np.uint8), (len(pts), 1))
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
        if self._occupancy is not None:
            self._occupancy.remove()
        self._occupancy = scene.add_image(
            "/map/occupancy", np.ascontiguousarray(rgba), render_width=w_m, render_height=h_m, position=centre,
            format="png", cast_shadow=False, receive_shadow=False,
        )
        oi, oj = np.nonzero(snap.obstacle)
        if len(oi):
            xy = snap.ij_to_xy(np.stack([oi, oj], axis=1)).astype(np.float32)
            levels = np.array([0.15, 0.6, 1.05], np.float32)
            step = max(1, int(math.ceil(len(xy) * len(levels) / self.config.max_obstacle_points)))
            xy = xy[::step]
            pts = np.concatenate(
                [np.concatenate([xy, np.full((len(xy), 1), z, np.float32)], axis=1) for z in levels], axis=0
            )
            colours = np.tile(np.array([[90, 100, 140]], np.uint8), (len(pts), 1))
            if self._obstacles is None:
                self._obstacles = scene.add_point_cloud("/map/obstacles", pts, colours, point_size=0.05)
            else:
                self._obstacles.points = pts
                self._obstacles.colors = colours


def _jpeg_rgb(jpeg: bytes) -> np.ndarray:
    import io

    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(jpeg)).convert("RGB"))


def _goal_picture(store: Any, run_id: str) -> np.ndarray:
    """The run's goal photo (runs/<id>/goal.png next to the store), grey if missing."""
    from pathlib import Path

    from PIL import Image

    path = Path(store.db_path).parent / "runs" / run_id / "goal.png"
    if path.is_file():
        return np.asarray(Image.open(path).convert("RGB"))
    return np.full((64, 64, 3), 200, np.uint8)
