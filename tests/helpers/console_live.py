"""Helpers of the console integration tests: a console with the real simulator and the
real Mod-IIN agent, a live uvicorn server, polling with deadlines."""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

from console.api import create_app
from console.context import Console, ConsoleConfig
from console.sim_provider import SimProvider, SimProviderConfig
from console.viewer import ViewerConfig
from tests.helpers.artifacts import artifacts_dir
from tests.helpers.polling import poll as poll  # re-exported for the integration tests

HOME_SEED = 0
ARTIFACTS = artifacts_dir("console")  # screenshots: outside the checkout


def sim_console(data_dir: Path, viewer: bool = False, realism: Any = None, **config: Any) -> Console:
    provider = SimProvider(data_dir, SimProviderConfig(home_seeds=(HOME_SEED,), realism=realism))
    assert provider.available()[0], "the simulator cache should be prepared by sim_data_dir"
    config.setdefault("allowed_hosts", ("testserver",))  # the TestClient's Host
    return Console(
        ConsoleConfig(data_dir=data_dir, viewer=ViewerConfig(port=0) if viewer else None, **config),
        {"sim": provider},
    )


class LiveServer:
    """The real app on the console's own uvicorn server (``imgnav console``'s) in a thread
    (browser tests, SSE)."""

    def __init__(self, console: Console) -> None:
        import uvicorn

        from console.server import ConsoleServer

        self.console = console
        # No graceful-shutdown timeout (the product has 5 s): a response that outlives the
        # shutdown (a page's status stream) is a failure of ``close`` here, not a silent wait.
        config = uvicorn.Config(create_app(console), host="127.0.0.1", port=0, log_level="warning")
        self.server = ConsoleServer(config, console.stop_for_shutdown)
        self.thread = threading.Thread(target=self.server.run, name="uvicorn", daemon=True)
        self.thread.start()
        poll(lambda: self.server.started, bool, 30, "uvicorn start")
        sock = self.server.servers[0].sockets[0]
        self.url = f"http://127.0.0.1:{sock.getsockname()[1]}"

    def close(self) -> None:
        """Stop the server as Ctrl-C does (pages may still be open), then the console."""
        self.server.should_exit = True
        self.thread.join(30)
        stopped = not self.thread.is_alive()
        self.console.close()
        assert stopped, "the console's server did not shut down within 30 s (an open response?)"
