"""API fuzzing with schemathesis against the app's own /openapi.json: generated requests
(valid and invalid) to every operation, no server error (5xx) allowed. A new route that can
be made to crash is caught here. Bounded: a few examples per operation, so it stays fast.

Random ids only reach the 404 branch of a route (issue 33: 13 of 19 operations mostly answered
404), so the console is given a real finished run (with its replay steps and artifacts) and a
real calibration job first, and the schema's id parameters are narrowed to those ids (and one
unknown id): generated requests then read, replay, stop, save and undo real records.

The two server-sent-event streams are left out: a valid request to them never ends (their
behaviour is tested in test_console_events.py and the API tests)."""

from __future__ import annotations

import copy
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
import schemathesis
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, given, settings
from schemathesis.checks import not_a_server_error

from agent.reid.base import Features, Matches
from agent.reid.identifier import ReIDConfig
from console.api import create_app
from console.calibration import Calibrator
from console.context import Console, ConsoleConfig
from tests.helpers.console_testkit import ScriptedProvider, encode, poll, textured_rgb

UNKNOWN_ID = "0123456789ab"


class _TopBandMatcher:
    """Stand-in for the matcher: photos whose top band is the same object match strongly."""

    name = "stand-in"

    def extract(self, rgb: np.ndarray, max_keypoints: int) -> Features:
        top = rgb[:8].reshape(-1, 3)[:64].astype(np.float32)
        return Features(np.zeros((1, 2), np.float32), top, (rgb.shape[1], rgb.shape[0]))

    def match(self, goal: Features, obs: Features) -> Matches:
        n = 40 if float(np.abs(goal.descriptors - obs.descriptors).mean()) < 30 else 4
        return Matches(np.arange(n), np.arange(n), np.full(n, 0.9 if n == 40 else 0.3, np.float32))


def _photo(obj: int, view: int) -> bytes:
    rgb = textured_rgb(96, 128, seed=1000 + 100 * obj + view)
    rgb[:16] = textured_rgb(16, 128, seed=obj)  # the object; the rest of the picture is the view
    return encode(rgb, "JPEG", quality=92)


@pytest.fixture(scope="module")
def fuzz_console(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Console, dict[str, Any]]]:
    """A console holding one finished run and one done calibration job; their ids."""
    console = Console(
        ConsoleConfig(data_dir=tmp_path_factory.mktemp("fuzz"), viewer=None, allowed_hosts=("testserver", "localhost")),
        {"scripted": ScriptedProvider(stop_after=3)},
    )
    console.calibrator = Calibrator(
        console.data_dir, matcher_for=lambda d: (_TopBandMatcher(), ReIDConfig(matcher="xfeat_lighterglue"))
    )
    with TestClient(create_app(console, close_on_shutdown=False)) as c:
        photo = {"goal_image": ("g.jpg", _photo(0, 0), "image/jpeg")}
        run_id = c.post("/api/runs", files=photo).json()["id"]
        poll(lambda: c.get(f"/api/runs/{run_id}").json()["status"], lambda s: s in ("finished", "stopped"))
        objects = [(name, obj, v) for obj, name in enumerate(["mug", "chair", "plant"]) for v in range(3)]
        files = [("photos", (f"{n}-{v}.jpg", _photo(o, v), "image/jpeg")) for n, o, v in objects]
        job = c.post("/api/calibration/sim", files=files, data={"objects": [n for n, _, _ in objects]}).json()
        poll(lambda: c.get(f"/api/calibration/jobs/{job['id']}").json()["state"], lambda s: s == "done")
        steps = len(c.get(f"/api/runs/{run_id}/replay").json()["steps"])
        artifacts = sorted(c.get(f"/api/runs/{run_id}").json()["artifacts"])
    assert steps >= 2 and artifacts
    yield console, {"run_id": run_id, "job_id": job["id"], "steps": steps, "artifacts": artifacts}
    console.close()


def _narrowed(raw: dict[str, Any], known: dict[str, Any]) -> dict[str, Any]:
    """The schema with its id parameters drawn from the real records (and one unknown id)."""
    choices: dict[str, list[Any]] = {
        "run_id": [known["run_id"], UNKNOWN_ID],
        "job_id": [known["job_id"], UNKNOWN_ID],
        "name": [*known["artifacts"], "console.sqlite3"],
        "step": [*range(known["steps"]), known["steps"] + 1000],
    }
    out = copy.deepcopy(raw)
    for ops in out["paths"].values():
        for op in ops.values():
            for param in op.get("parameters", []):
                if param["in"] == "path" and param["name"] in choices:
                    param["schema"] = {"enum": choices[param["name"]]}
    return out


@pytest.fixture(scope="module")
def api_schema(fuzz_console: tuple[Console, dict[str, Any]]):
    console, known = fuzz_console
    app = create_app(console, close_on_shutdown=False)
    with TestClient(app) as c:
        raw = c.get("/openapi.json").json()
    schema = schemathesis.openapi.from_dict(_narrowed(raw, known))
    schema.app = app
    return schema.exclude(path_regex=r"events$")


# operations that must answer 2xx to at least one generated request: the deep paths
DEEP = {
    "GET /api/runs/{run_id}",
    "GET /api/runs/{run_id}/artifacts/{name}",
    "GET /api/runs/{run_id}/replay",
    "GET /api/runs/{run_id}/replay/latest",
    "GET /api/runs/{run_id}/replay/{step}",
    "GET /api/runs/{run_id}/replay/{step}/frame.jpg",
    "GET /api/runs/{run_id}/replay/{step}/map.png",
    "GET /api/calibration/jobs/{job_id}",
    "POST /api/calibration/jobs/{job_id}/save",
    "GET /api/calibration/jobs",
}


def test_no_server_error(api_schema) -> None:
    # Hypothesis over each operation's case strategy (schemathesis's pytest plugin does not load
    # under this pytest); every failing operation is reported, not just the first.
    failures: list[str] = []
    calls: dict[str, int] = {}
    statuses: dict[str, set[int]] = {}
    for result in api_schema.get_all_operations():
        operation = result.ok()
        label = f"{operation.method.upper()} {operation.path}"

        @given(case=operation.as_strategy())
        @settings(
            max_examples=12, deadline=None, database=None, derandomize=True, suppress_health_check=list(HealthCheck)
        )
        def fuzz(case) -> None:
            # fuzz() runs within this iteration, so the loop variable is the one it was built for
            calls[label] = calls.get(label, 0) + 1  # noqa: B023
            response = case.call_and_validate(checks=[not_a_server_error])
            statuses.setdefault(label, set()).add(response.status_code)  # noqa: B023

        try:
            fuzz()
        except Exception as exc:  # collect and report all operations' failures together
            failures.append(f"{label}: {exc}")
    assert not failures, "\n\n".join(failures)
    assert len(calls) >= 8 and min(calls.values()) >= 1, calls  # every path was exercised
    shallow = sorted(op for op in DEEP if not any(200 <= s < 300 for s in statuses.get(op, ())))
    assert not shallow, {op: sorted(statuses.get(op, ())) for op in shallow}  # reached real records


def test_fuzzing_covers_the_state_changing_routes(api_schema) -> None:
    paths = {op.path for op in (result.ok() for result in api_schema.get_all_operations())}
    assert {"/api/runs", "/api/runs/{run_id}/stop", "/api/runs/{run_id}/artifacts/{name}"} <= paths, paths
    assert {"/api/calibration/jobs/{job_id}/save", "/api/calibration/{deployment}/undo"} <= paths, paths
    assert not any(p.endswith("events") for p in paths)
