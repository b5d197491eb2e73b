"""The viewer: one viser server with its parts put together.

* ``guard``: the websocket handshake check (Host and Origin, as the API's requests);
* ``controls``: each browser's own stop control (token box, Stop button, note);
* ``scene``: the live scene and panels that draw a step;
* ``throttle``: the publishing thread (the worker only offers its newest step);
* ``replay_gui``: the replay of a finished run, step by step.

viser handles are touched by the run manager's worker (``run_started``/``run_ended``), the
publishing thread and viser's own threads (clicks, the slider): one re-entrant lock guards them
all (a slider set under it runs its callback on the same thread).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from console.security import LOOPBACK_NAMES
from console.session import Outcome, StepRecord
from console.viewer.config import ViewerConfig
from console.viewer.controls import StopControls
from console.viewer.guard import HandshakeGuard
from console.viewer.replay_gui import ReplayGui
from console.viewer.scene import LiveScene
from console.viewer.throttle import Throttle
from console.words import run_summary

logger = logging.getLogger(__name__)


class Viewer:
    """Owns the viser server, its parts and the publishing thread (the run manager's ``ViewerSink``)."""

    def __init__(
        self,
        config: ViewerConfig | None = None,
        on_stop: Callable[[], str] | None = None,
        token: str | None = None,
        allowed_hosts: Sequence[str] = LOOPBACK_NAMES,
    ) -> None:
        import viser  # heavy import, only when a viewer is wanted

        config = config if config is not None else ViewerConfig()
        self.config = config
        self.server = viser.ViserServer(host=config.host, port=config.port, label="imgnav", verbose=False)
        # Before any client can have finished its handshake: reject foreign Host/Origin.
        self.guard = HandshakeGuard(allowed_hosts)
        self.guard.install(self.server)
        # The share button asks an outside service for a public tunnel: never offer it.
        # The side panel beside the scene, not over it (a floating "large" panel hid ~45% of the scene
        # at 1280 x 800, issue 33), narrow, and collapsible for the whole width.
        self.server.gui.configure_theme(show_share_button=False, show_logo=False, control_width="small")
        self.server.gui.main_panel.dock_right()
        self.server.scene.set_up_direction("+z")
        # Plain lights, no image-based lighting: viser's default environment map (an HDRI) costs a
        # browser without a GPU (software WebGL) 8-12 s of frozen page when the first lit object
        # appears, and the scene (a map, a path, a robot) gains nothing from reflections. Its
        # default lights shine from above and below; an ambient light lights the sides.
        self.server.scene.configure_environment_map(None)
        self.server.scene.configure_default_lights(enabled=True, cast_shadow=False)
        self.server.scene.add_light_ambient("/ambient_light", intensity=1.5)
        # Look down on the start area from behind and above (a home is ~5-10 m across).
        self.server.initial_camera.position = (-4.0, -4.0, 7.0)
        self.server.initial_camera.look_at = (1.5, 1.5, 0.0)
        self._handles_lock = threading.RLock()
        self.scene = LiveScene(self.server, config)
        self.replay = ReplayGui(self.server, self.scene, self._handles_lock, self._publish_replayed)
        self.controls = StopControls(self._handles_lock, on_stop, token)
        self.controls.install(self.server)
        self.n_published = 0
        self.last_published_step: int | None = None
        self._throttle = Throttle(self.publish, config.pose_hz, config.map_hz)
        logger.info("viewer (viser) on port %d", self.port)

    @property
    def port(self) -> int:
        return int(self.server.get_port())

    @property
    def n_rejected(self) -> int:
        """Connections the handshake guard closed."""
        return self.guard.n_rejected

    @property
    def replay_step(self) -> int | None:
        """The step of a finished run shown last (None: no replay yet)."""
        return self.replay.step

    # --- called by the run manager (worker thread): must be cheap ---------------

    def run_started(self, run_id: str, goal_rgb: np.ndarray, info: Mapping[str, Any]) -> None:
        self._throttle.take()  # a record of the run before must not be drawn over this one
        with self._handles_lock:
            self.scene.status.content = f"**Run {run_id}** - starting ({info.get('backend', '')})"
            self.scene.show_goal(goal_rgb)
            self.controls.set_enabled(True)
            self.replay.end()
            self.scene.clear()

    def offer(self, rec: StepRecord) -> None:
        self._throttle.offer(rec)

    def run_ended(self, run_id: str, status: str, outcome: Outcome, summary: Mapping[str, str] | None = None) -> None:
        """Draw the run's final step (whatever the throttle said) and say how it ended, in the
        pages' words (``summary``: ``console.words.run_summary`` of the run), under its last step."""
        latest = self._throttle.take()
        if latest is not None and latest.run_id == run_id:
            self.publish(latest, with_map=True)
        if summary is None:
            summary = run_summary(
                {
                    "status": status,
                    "outcome": outcome.outcome,
                    "outcome_detail": outcome.detail,
                    "metrics": outcome.metrics,
                }
            )
        with self._handles_lock:
            ended = f"**Run {run_id}** - {summary['headline']}. {summary['sentence']}"
            last = self.scene.step_words  # this run's last step drawn (run_started cleared the scene)
            self.scene.status.content = ended + (f"\n\nLast step: {last}" if last else "")
            self.controls.set_enabled(False)

    # --- drawing ----------------------------------------------------------------------

    def publish(self, rec: StepRecord, with_map: bool) -> None:
        """Send one step to the browsers (pose, images; the map too if ``with_map``)."""
        with self._handles_lock:
            self._throttle.stamp(with_map)
            self.scene.publish(rec, with_map)
        self.n_published += 1
        self.last_published_step = rec.step

    def _publish_replayed(self, rec: StepRecord) -> None:
        with self._handles_lock:
            self._throttle.stamp(True)
            self.scene.publish(rec, with_map=True, replay=True)

    # --- replay of a finished run (console.replay) ------------------------------------------

    def show_replay(
        self,
        store: Any,
        row: Mapping[str, Any],
        steps: list[dict[str, Any]],
        extras: Mapping[int, Mapping[str, Any]],
        step: int,
    ) -> None:
        """Show one step of a finished run (``console.viewer.replay_gui``)."""
        self.replay.show(store, row, steps, extras, step)

    def close(self) -> None:
        self._throttle.close()
        self.server.stop()
