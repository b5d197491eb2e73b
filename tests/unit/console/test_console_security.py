"""Token and bind-address rules, the Host check (DNS rebinding), one console per data
directory (across processes) and the start-up URLs for phones."""

from __future__ import annotations

import subprocess
import sys
import textwrap
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from console import server as console_server
from console.api import create_app
from console.context import Console, ConsoleConfig
from console.datalock import DataDirLocked
from console.security import allowed_hosts, host_allowed, is_loopback, token_matches
from tests.helpers.console_testkit import ScriptedProvider, encode, poll, textured_rgb


def test_loopback_detection() -> None:
    assert is_loopback("127.0.0.1") and is_loopback("::1") and is_loopback("localhost")
    assert not is_loopback("0.0.0.0") and not is_loopback("192.168.1.20") and not is_loopback("::")


def test_token_required_off_loopback() -> None:
    assert not ConsoleConfig(host="127.0.0.1").token_required()
    assert ConsoleConfig(host="0.0.0.0").token_required()
    assert ConsoleConfig(host="127.0.0.1", token="abc").token_required()


def test_token_matching() -> None:
    assert token_matches(None, None)
    assert token_matches("abc", "abc") and token_matches("abc", " abc ")
    assert not token_matches("abc", "abd") and not token_matches("abc", None) and not token_matches("abc", "")


# --- Host check ---------------------------------------------------------------------


def test_allowed_host_names(monkeypatch: pytest.MonkeyPatch) -> None:
    loop = allowed_hosts("127.0.0.1")
    assert {"localhost", "127.0.0.1", "[::1]"} <= set(loop)
    assert "0.0.0.0" not in loop and "evil.example" not in loop
    monkeypatch.setattr("console.security.interface_addresses", lambda: ["192.168.1.20"])
    monkeypatch.setattr("console.security.socket.gethostname", lambda: "workbench")
    everywhere = allowed_hosts("0.0.0.0", ["robot-console.lan"])
    assert {"192.168.1.20", "workbench", "workbench.local", "robot-console.lan", "localhost"} <= set(everywhere)
    assert allowed_hosts("::1") == ["localhost", "127.0.0.1", "[::1]"]
    assert host_allowed("localhost:8000", loop) and host_allowed("[::1]:8000", loop) and host_allowed("127.0.0.1", loop)
    assert not host_allowed("evil.example:8000", loop) and not host_allowed("", loop) and not host_allowed(None, loop)
    assert not host_allowed("127.0.0.1.evil.example", loop) and not host_allowed("localhost:80:80", loop)


@pytest.fixture
def loopback_console(tmp_path: Path) -> Iterator[tuple[Console, TestClient, ScriptedProvider]]:
    """A loopback console (no token: the Host check is all that stands against rebinding)."""
    provider = ScriptedProvider(stop_after=10_000)
    console = Console(ConsoleConfig(data_dir=tmp_path, viewer=None, port=8775), {"scripted": provider})
    client = TestClient(create_app(console), base_url="http://127.0.0.1:8775")
    with client:
        yield console, client, provider
    console.close()


def _photo() -> dict:
    return {"goal_image": ("g.jpg", encode(textured_rgb(120, 160), "JPEG"), "image/jpeg")}


def test_dns_rebinding_is_refused_on_every_route(loopback_console) -> None:
    """The attack of issue 11: a page on evil.example, rebound to 127.0.0.1, sends requests
    whose Host and Origin are both evil.example:8775 (so the Origin check alone passes)."""
    console, client, provider = loopback_console
    provider.gate = gate = threading.Event()
    run = client.post("/api/runs", files=_photo())
    assert run.status_code == 201, run.text
    run_id = run.json()["id"]
    forged = {"Host": "evil.example:8775", "Origin": "http://evil.example:8775"}
    attempts = [
        client.post("/api/runs", files=_photo(), headers=forged),
        client.post(f"/api/runs/{run_id}/stop", headers=forged),
        client.get(f"/api/runs/{run_id}/artifacts/goal.png", headers=forged),
        client.get(f"/api/runs/{run_id}/artifacts/goal_upload.jpg", headers=forged),
        client.get(f"/api/runs/{run_id}", headers=forged),
        client.get("/api/runs", headers=forged),
        client.get("/api/config", headers=forged),
        client.get(f"/api/runs/{run_id}/events", headers=forged),
        client.get("/", headers=forged),
        # Host alone (no Origin: a rebinding page's GET, or curl pretending)
        client.post(f"/api/runs/{run_id}/stop", headers={"Host": "evil.example:8775"}),
    ]
    for resp in attempts:
        assert resp.status_code == 400, (resp.request.method, resp.request.url, resp.status_code, resp.text)
        assert "goal" not in resp.headers.get("content-type", "") and "image" not in resp.headers.get(
            "content-type", ""
        )
    assert console.manager.active_run_id == run_id  # still running: the forged stop did nothing
    assert console.store.get_run(run_id)["status"] == "running"
    assert len(client.get("/api/runs").json()["runs"]) == 1  # the forged start created nothing
    # The console's real names pass, with and without a port.
    for host in ("127.0.0.1:8775", "localhost:8775", "localhost", "[::1]:8775"):
        assert client.get("/api/config", headers={"Host": host}).status_code == 200, host
    # ...and a same-origin stop under a real name works.
    stop = client.post(
        f"/api/runs/{run_id}/stop", headers={"Host": "localhost:8775", "Origin": "http://localhost:8775"}
    )
    assert stop.status_code == 200 and stop.json()["stopping"] is True
    gate.set()
    poll(lambda: client.get(f"/api/runs/{run_id}").json()["status"], lambda s: s == "stopped")


def test_allowed_host_option_adds_a_name(tmp_path: Path) -> None:
    console = Console(
        ConsoleConfig(data_dir=tmp_path, viewer=None, allowed_hosts=("robot-console.lan",)),
        {"scripted": ScriptedProvider()},
    )
    try:
        with TestClient(create_app(console), base_url="http://robot-console.lan:8000") as client:
            assert client.get("/api/config").status_code == 200
            assert client.get("/api/config", headers={"Host": "other.lan:8000"}).status_code == 400
    finally:
        console.close()


# --- one console per data directory ---------------------------------------------------

_HOLDER = textwrap.dedent(
    """
    import sys
    from console.context import Console, ConsoleConfig
    console = Console(ConsoleConfig(data_dir=sys.argv[1], viewer=None, port=8123), {})
    print("ready", flush=True)
    sys.stdin.readline()   # hold the data directory until the test says so
    console.close()
    print("closed", flush=True)
    """
)


def test_second_console_on_a_data_directory_fails_naming_the_first(tmp_path: Path) -> None:
    holder = subprocess.Popen(
        [sys.executable, "-c", _HOLDER, str(tmp_path)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "ready"
        with pytest.raises(DataDirLocked) as err:
            Console(ConsoleConfig(data_dir=tmp_path, viewer=None), {"scripted": ScriptedProvider()})
        message = str(err.value)
        assert f"pid {holder.pid}" in message and "8123" in message and str(tmp_path) in message
        # The refused console changed nothing: no run was marked, the lock is still the holder's.
        assert "another imgnav console" in message
        holder.stdin.write("\n")
        holder.stdin.flush()
        assert holder.stdout.readline().strip() == "closed"
        assert holder.wait(30) == 0
    finally:
        if holder.poll() is None:
            holder.kill()
    # Once the holder is gone, a console opens the directory.
    console = Console(ConsoleConfig(data_dir=tmp_path, viewer=None), {"scripted": ScriptedProvider()})
    console.close()


def test_a_killed_console_does_not_block_the_next(tmp_path: Path) -> None:
    holder = subprocess.Popen(
        [sys.executable, "-c", _HOLDER, str(tmp_path)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        assert holder.stdout.readline().strip() == "ready"
        holder.kill()  # SIGKILL: no clean-up runs; the kernel drops the flock
        holder.wait(30)
    finally:
        if holder.poll() is None:
            holder.kill()
    console = Console(ConsoleConfig(data_dir=tmp_path, viewer=None), {"scripted": ScriptedProvider()})
    console.close()


def test_imgnav_console_exits_with_the_message_when_the_directory_is_held(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    first = Console(ConsoleConfig(data_dir=tmp_path, viewer=None, port=8001), {})
    try:
        parser = __import__("argparse").ArgumentParser()
        console_server.add_arguments(parser)
        args = parser.parse_args(["--data-dir", str(tmp_path), "--no-viewer", "--port", "8002"])
        with caplog.at_level("ERROR"):
            assert console_server.run(args) == 1
        assert "in use by another imgnav console" in caplog.text and "8001" in caplog.text
    finally:
        first.close()


# --- start-up URLs ----------------------------------------------------------------------


def test_wildcard_bind_prints_this_machines_addresses(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(console_server, "interface_addresses", lambda: ["192.168.1.20", "10.0.0.7"])
    urls = console_server.console_urls("0.0.0.0", 8000, "tok")
    assert urls == ["http://192.168.1.20:8000/?token=tok", "http://10.0.0.7:8000/?token=tok"]
    assert console_server.console_urls("127.0.0.1", 8000, None) == ["http://127.0.0.1:8000/"]


def test_interface_addresses_are_not_loopback() -> None:
    from console.security import interface_addresses

    addresses = interface_addresses()
    assert all(not a.startswith("127.") for a in addresses), addresses


def test_origin_of_another_scheme_or_a_second_host_is_refused(loopback_console) -> None:
    """Issue 33: ``https://127.0.0.1:PORT`` is another origin than the console's
    ``http://127.0.0.1:PORT`` (a page served over TLS under the same name); and a request with
    two Host headers does not get to choose which one the checks read."""
    console, client, _ = loopback_console
    for origin in ("https://127.0.0.1:8775", "ws://127.0.0.1:8775", "ftp://127.0.0.1:8775"):
        resp = client.post("/api/runs", files=_photo(), headers={"Host": "127.0.0.1:8775", "Origin": origin})
        assert resp.status_code == 403 and resp.json()["detail"]["code"] == "cross_origin", (origin, resp.text)
    two_hosts = client.post(
        "/api/runs", files=_photo(), headers=[("Host", "127.0.0.1:8775"), ("Host", "evil.example:8775")]
    )
    assert two_hosts.status_code == 400, two_hosts.text
    two_origins = client.post(
        "/api/runs",
        files=_photo(),
        headers=[("Origin", "http://127.0.0.1:8775"), ("Origin", "http://evil.example:8775")],
    )
    assert two_origins.status_code == 400 and two_origins.json()["detail"]["code"] == "duplicate_header"
    assert client.get("/api/runs").json()["runs"] == []  # none of them started anything
    same = client.post("/api/calibration/sim/undo", headers={"Origin": "http://127.0.0.1:8775"})
    assert same.status_code == 409  # the right scheme passes the Origin check (nothing to undo)


def _viewer_handshake(port: int, origin: str | None, extra: list[tuple[str, str]]) -> tuple[str, object]:
    import socket

    import viser
    from websockets.exceptions import ConnectionClosed, InvalidStatus
    from websockets.sync.client import connect

    sock = socket.create_connection(("127.0.0.1", port), timeout=10)
    try:
        ws = connect(
            f"ws://127.0.0.1:{port}/",
            sock=sock,
            origin=origin,  # type: ignore[arg-type]
            additional_headers=extra,
            subprotocols=[f"viser-v{viser.__version__}"],  # type: ignore[list-item]
            open_timeout=10,
            close_timeout=2,
        )
    except InvalidStatus as exc:  # refused by the websocket library's own handshake
        return "http", exc.response.status_code
    with ws:
        try:
            return "message", ws.recv(timeout=10)
        except ConnectionClosed as exc:
            return "closed", exc.rcvd.code if exc.rcvd is not None else None


def test_viewer_refuses_another_scheme_and_two_hosts_cleanly(caplog: pytest.LogCaptureFixture) -> None:
    from console.viewer import Viewer, ViewerConfig

    viewer = Viewer(ViewerConfig(port=0))
    try:
        port = viewer.port
        cases = [
            (f"https://127.0.0.1:{port}", []),
            (None, [("Host", "evil.example")]),  # a second Host header
        ]
        for k, (origin, extra) in enumerate(cases, start=1):
            with caplog.at_level("WARNING"):
                assert _viewer_handshake(port, origin, extra) == ("closed", 1008), (origin, extra)
            assert viewer.n_rejected == k
        assert not [r for r in caplog.records if r.exc_info], "an exception on the way to the refusal"
        # two Origins: the websocket library answers 400 before the guard sees the request
        assert _viewer_handshake(port, f"http://127.0.0.1:{port}", [("Origin", "http://evil.example")]) == (
            "http",
            400,
        )
        assert _viewer_handshake(port, f"http://127.0.0.1:{port}", [])[0] == "message"
    finally:
        viewer.close()


def test_a_run_id_is_exactly_twelve_hex_digits() -> None:
    from console.artifacts import run_dir, valid_run_id

    assert valid_run_id("0123456789ab")
    for bad in ("0123456789ab\n", "0123456789AB", "0123456789a", "0123456789abc", "../456789ab", ""):
        assert not valid_run_id(bad), repr(bad)
        with pytest.raises(ValueError):
            run_dir(Path("/tmp/data"), bad)
