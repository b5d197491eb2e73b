"""The HTTP API over a scripted backend: run lifecycle, 409, stop, recovery, every bad input.

Whole runs with the real simulator are in tests/integration/console."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from console.api import create_app
from console.context import Console, ConsoleConfig
from console.photos import PhotoLimits
from tests.helpers.console_testkit import ScriptedProvider, encode, poll, textured_rgb


def make(tmp_path: Path, provider: ScriptedProvider, **config: Any) -> tuple[Console, TestClient]:
    config.setdefault("allowed_hosts", ("testserver",))  # the TestClient's Host
    console = Console(ConsoleConfig(data_dir=tmp_path, viewer=None, **config), {"scripted": provider})
    return console, TestClient(create_app(console))


@pytest.fixture
def provider() -> ScriptedProvider:
    return ScriptedProvider(stop_after=4)


@pytest.fixture
def client(tmp_path: Path, provider: ScriptedProvider) -> Iterator[TestClient]:
    console, client = make(tmp_path, provider)
    with client:
        yield client
    console.close()


def photo(fmt: str = "JPEG") -> tuple[str, bytes, str]:
    return ("goal.jpg", encode(textured_rgb(120, 160), fmt), "image/jpeg")


def wait_done(client: TestClient, run_id: str) -> dict:
    return poll(
        lambda: client.get(f"/api/runs/{run_id}").json(), lambda r: r["status"] in ("finished", "stopped", "failed")
    )


def test_photo_alone_starts_a_run_that_is_recorded(client: TestClient, tmp_path: Path) -> None:
    resp = client.post("/api/runs", files={"goal_image": photo()})
    assert resp.status_code == 201, resp.text
    run = resp.json()
    assert run["backend"] == "scripted" and run["status"] in ("pending", "running")
    done = wait_done(client, run["id"])
    assert done["status"] == "finished" and done["outcome"] == "unscored"
    assert done["n_steps"] == 5  # 4 moves and the STOP
    assert done["agent_config"] == {"name": "scripted"}
    assert done["timings"]["upload_to_first_action_s"] > 0
    full = client.get(f"/api/runs/{run['id']}", params={"steps": True}).json()
    assert [s["action"] for s in full["steps"]] == [1, 2, 1, 2, 0]
    assert full["steps"][2]["reid_score"] == 2.0 and full["steps"][0]["mode"] == "explore"
    assert set(done["artifacts"]) >= {"goal.png", "goal_upload.jpg", "trajectory.json", "map.png", "run.webp"}
    traj = client.get(done["artifacts"]["trajectory.json"]).json()
    assert len(traj["steps"]) == 5 and traj["summary"]["outcome"] == "unscored"
    assert client.get(done["artifacts"]["run.webp"]).headers["content-type"] == "image/webp"
    listed = client.get("/api/runs").json()
    assert listed["runs"][0]["id"] == run["id"] and listed["active_run"] is None
    files = {p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*") if p.is_file()}
    assert all(
        f.startswith(f"runs/{run['id']}/") or f.startswith("console.sqlite3") or f == "console.lock" for f in files
    ), files


def test_one_step_schema_for_the_api_the_event_stream_and_trajectory_json(tmp_path: Path) -> None:
    console, client = make(tmp_path, ScriptedProvider(stop_after=3))
    events: list[dict] = []
    publish = console.hub.publish

    def spy(kind: str, run_id: str | None, data: Any):  # every event the hub sends, as sent
        if kind == "step":
            events.append(dict(data))
        return publish(kind, run_id, data)

    console.hub.publish = spy  # type: ignore[method-assign]
    with client:
        run = client.post("/api/runs", files={"goal_image": photo()}).json()
        done = wait_done(client, run["id"])
        api_steps = client.get(f"/api/runs/{run['id']}", params={"steps": True}).json()["steps"]
        traj_steps = client.get(done["artifacts"]["trajectory.json"]).json()["steps"]
    console.close()
    assert len(api_steps) == 4 and api_steps == traj_steps
    assert [{k: v for k, v in e.items() if k != "status"} for e in events] == api_steps
    assert api_steps[1]["action_name"] == "TURN_LEFT" and {"reid_full_matcher", "reid_gate_score", "timings"} <= set(
        api_steps[1]
    )
    # the agent's event (AgentRecord.event) is carried like every field of console.step_schema.StepRow
    assert [s["event"] for s in api_steps] == ["frontier", "frontier", "frontier", "stop_at_goal"]


def test_second_run_gets_409_and_stop_ends_the_first(client: TestClient, provider: ScriptedProvider) -> None:
    provider.stop_after = 10_000
    provider.gate = gate = threading.Event()  # hold the robot inside apply()
    first = client.post("/api/runs", files={"goal_image": photo()}).json()
    second = client.post("/api/runs", files={"goal_image": photo()})
    assert second.status_code == 409 and second.json()["detail"]["code"] == "run_active"
    stop = client.post(f"/api/runs/{first['id']}/stop")
    assert stop.status_code == 200 and stop.json()["stopping"] is True
    gate.set()
    done = wait_done(client, first["id"])
    assert done["status"] == "stopped" and done["outcome"] == "stopped"
    assert provider.sessions[0].backend.closed
    assert len(provider.sessions[0].backend.applied) == done["n_steps"]  # nothing sent after the stop
    again = client.post("/api/runs", files={"goal_image": photo()}, data={"max_steps": "3"})
    assert again.status_code == 201
    wait_done(client, again.json()["id"])


def test_stop_mid_run(client: TestClient, provider: ScriptedProvider) -> None:
    provider.stop_after = 10_000
    run = client.post("/api/runs", files={"goal_image": photo()}).json()
    poll(lambda: client.get(f"/api/runs/{run['id']}").json()["n_steps"], lambda n: n >= 3)
    assert client.post(f"/api/runs/{run['id']}/stop").json()["stopping"]
    # read after the stop was accepted: at most the step under way when it came is added
    at_stop = len(provider.sessions[0].backend.applied)
    done = wait_done(client, run["id"])
    assert done["status"] == "stopped" and 3 <= done["n_steps"] <= at_stop + 1


def test_backend_error_fails_the_run_cleanly(client: TestClient, provider: ScriptedProvider) -> None:
    provider.fail_at = 2
    provider.stop_after = 100
    run = client.post("/api/runs", files={"goal_image": photo()}).json()
    done = wait_done(client, run["id"])
    assert done["status"] == "failed" and done["outcome"] == "error"
    assert "disconnected" in done["outcome_detail"] and provider.sessions[0].backend.closed


def test_max_steps_budget(client: TestClient, provider: ScriptedProvider) -> None:
    provider.stop_after = 10_000
    run = client.post("/api/runs", files={"goal_image": photo()}, data={"max_steps": "3"}).json()
    done = wait_done(client, run["id"])
    assert done["n_steps"] == 3 and done["status"] == "finished"


@pytest.mark.parametrize(
    "files, data, status, code",
    [
        ({"goal_image": ("g.jpg", b"", "image/jpeg")}, {}, 400, "empty"),
        ({"goal_image": ("g.pdf", b"%PDF-1.4 not an image" * 20, "application/pdf")}, {}, 415, "unsupported_format"),
        ({"goal_image": ("g.bmp", encode(textured_rgb(64, 64), "BMP"), "image/bmp")}, {}, 415, "unsupported_format"),
        ({"goal_image": ("g.jpg", encode(textured_rgb(200, 200), "JPEG")[:600], "image/jpeg")}, {}, 422, "corrupt"),
        ({"goal_image": ("g.png", encode(textured_rgb(16, 16), "PNG"), "image/png")}, {}, 422, "too_small"),
        ({"goal_image": photo()}, {"backend": "warp-drive"}, 422, "unknown_backend"),
        ({"goal_image": photo()}, {"home": "nowhere"}, 422, "bad_options"),
        ({"goal_image": photo()}, {"max_steps": "many"}, 422, None),
    ],
)
def test_bad_inputs(client: TestClient, files: dict, data: dict, status: int, code: str | None) -> None:
    resp = client.post("/api/runs", files=files, data=data)
    assert resp.status_code == status, resp.text
    if code is not None:
        assert resp.json()["detail"]["code"] == code
        assert resp.json()["detail"]["message"]
    assert client.get("/api/runs").json()["runs"] == []


def test_missing_photo_is_422(client: TestClient) -> None:
    resp = client.post("/api/runs", data={"backend": "scripted"})
    assert resp.status_code == 422


def test_size_limits(tmp_path: Path, provider: ScriptedProvider) -> None:
    console, client = make(
        tmp_path, provider, max_request_bytes=50_000, photo_limits=PhotoLimits(max_bytes=20_000, max_pixels=40_000)
    )
    with client:
        noise = np.random.default_rng(0).integers(0, 255, size=(400, 400, 3), dtype=np.uint8)
        big = encode(noise, "PNG")
        assert len(big) > 50_000
        resp = client.post("/api/runs", files={"goal_image": ("g.png", big, "image/png")})
        assert resp.status_code == 413 and resp.json()["detail"]["code"] == "request_too_large"
        mid = encode(noise[:100, :100], "PNG")
        assert 20_000 < len(mid) < 50_000
        resp = client.post("/api/runs", files={"goal_image": ("g.png", mid, "image/png")})
        assert resp.status_code == 413 and resp.json()["detail"]["code"] == "too_large"
        many = encode(textured_rgb(300, 300)[:, :, 0] * 0 + 1, "PNG")  # small file, 90k pixels
        resp = client.post("/api/runs", files={"goal_image": ("g.png", many, "image/png")})
        assert resp.status_code == 413 and resp.json()["detail"]["code"] == "too_many_pixels"
    console.close()


def test_token_required_when_configured(tmp_path: Path, provider: ScriptedProvider) -> None:
    console, client = make(tmp_path, provider, host="0.0.0.0")
    assert console.token
    with client:
        assert client.get("/api/config").json()["token_required"] is True
        assert client.post("/api/runs", files={"goal_image": photo()}).status_code == 401
        assert (
            client.post("/api/runs", files={"goal_image": photo()}, headers={"X-Imgnav-Token": "wrong"}).status_code
            == 401
        )
        ok = client.post(
            "/api/runs", files={"goal_image": photo()}, headers={"Authorization": f"Bearer {console.token}"}
        )
        assert ok.status_code == 201
        run_id = ok.json()["id"]
        assert client.post(f"/api/runs/{run_id}/stop").status_code == 401
        assert (
            client.post(f"/api/runs/{run_id}/stop", data={}, headers={"X-Imgnav-Token": console.token}).status_code
            == 200
        )
        wait_done(client, run_id)
        form_token = client.post("/api/runs", files={"goal_image": photo()}, data={"token": console.token})
        assert form_token.status_code == 201
        wait_done(client, form_token.json()["id"])
    console.close()


def test_cross_origin_post_refused_and_no_cors(client: TestClient) -> None:
    resp = client.post("/api/runs", files={"goal_image": photo()}, headers={"Origin": "http://evil.example"})
    assert resp.status_code == 403 and resp.json()["detail"]["code"] == "cross_origin"
    pre = client.options(
        "/api/runs", headers={"Origin": "http://evil.example", "Access-Control-Request-Method": "POST"}
    )
    assert "access-control-allow-origin" not in pre.headers
    same = client.post("/api/runs", files={"goal_image": photo()}, headers={"Origin": "http://testserver"})
    assert same.status_code == 201
    wait_done(client, same.json()["id"])


def test_unknown_runs_and_artifact_names(client: TestClient) -> None:
    assert client.get("/api/runs/0123456789ab").status_code == 404
    assert client.get("/api/runs/../../etc").status_code == 404
    assert client.post("/api/runs/0123456789ab/stop").status_code == 404
    run = client.post("/api/runs", files={"goal_image": photo()}).json()
    wait_done(client, run["id"])
    assert client.get(f"/api/runs/{run['id']}/artifacts/..%2F..%2Fconsole.sqlite3").status_code == 404
    assert client.get(f"/api/runs/{run['id']}/artifacts/console.sqlite3").status_code == 404
    assert client.get(f"/api/runs/{run['id']}/artifacts/goal.png").status_code == 200
    assert client.get("/static/..%2Fpyproject.toml").status_code == 404


def test_pages_and_docs(client: TestClient) -> None:
    for path in ("/", "/phone", "/console", "/static/app.css", "/static/common.js", "/docs", "/openapi.json"):
        assert client.get(path).status_code == 200, path
    assert 'capture="environment"' in client.get("/phone").text
    spec = client.get("/openapi.json").json()
    assert "/api/runs" in spec["paths"] and "/api/runs/{run_id}/stop" in spec["paths"]


def test_restart_marks_the_active_run_interrupted(tmp_path: Path) -> None:
    provider = ScriptedProvider(stop_after=10_000)
    provider.gate = threading.Event()
    console, client = make(tmp_path, provider)
    run = client.post("/api/runs", files={"goal_image": photo()}).json()
    # The process "dies": nothing closes the store and the worker is stuck in apply(); the
    # kernel drops a dead process's flock, which releasing it here stands in for.
    console.lock.release()
    console2, client2 = make(tmp_path, ScriptedProvider())
    row = client2.get(f"/api/runs/{run['id']}").json()
    assert row["status"] == "interrupted" and row["outcome"] == "interrupted"
    provider.gate.set()
    console.close()
    console2.close()


def test_upload_with_a_very_long_file_name_gets_a_clear_400(client: TestClient) -> None:
    name = "a" * 10_000 + ".jpg"
    resp = client.post("/api/runs", files={"goal_image": (name, encode(textured_rgb(120, 160), "JPEG"), "image/jpeg")})
    assert resp.status_code == 400, resp.text
    detail = resp.json()["detail"]
    assert detail["code"] == "bad_form" and "file name" in detail["message"], detail
    assert client.get("/api/runs").json()["runs"] == []


def test_flat_coloured_photo_is_refused_at_upload(client: TestClient) -> None:
    solid = encode(np.full((64, 64, 3), (200, 100, 50), np.uint8), "PNG")
    resp = client.post("/api/runs", files={"goal_image": ("g.png", solid, "image/png")})
    assert resp.status_code == 422 and resp.json()["detail"]["code"] == "blank"


def test_huge_list_offset_is_a_422_not_a_crash(client: TestClient) -> None:
    """Found by the API fuzz run: an offset beyond SQLite's integer range was a 500."""
    assert client.get("/api/runs", params={"offset": 2**70}).status_code == 422
    assert client.get("/api/runs", params={"offset": 5}).json()["runs"] == []
