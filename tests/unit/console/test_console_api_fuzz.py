"""API fuzzing with schemathesis against the app's own /openapi.json: generated requests
(valid and invalid) to every operation, no server error (5xx) allowed. A new route that can
be made to crash is caught here. Bounded: a few examples per operation, so it stays fast.

The two server-sent-event streams are left out: a valid request to them never ends (their
behaviour is tested in test_console_events.py and the API tests)."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
import schemathesis
from hypothesis import HealthCheck, given, settings
from schemathesis.checks import not_a_server_error

from console.api import create_app
from console.context import Console, ConsoleConfig
from tests.helpers.console_testkit import ScriptedProvider


@pytest.fixture(scope="module")
def fuzz_console(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Console]:
    console = Console(
        ConsoleConfig(data_dir=tmp_path_factory.mktemp("fuzz"), viewer=None, allowed_hosts=("testserver", "localhost")),
        {"scripted": ScriptedProvider(stop_after=3)},
    )
    yield console
    console.close()


@pytest.fixture(scope="module")
def api_schema(fuzz_console: Console):
    app = create_app(fuzz_console, close_on_shutdown=False)
    return schemathesis.openapi.from_asgi("/openapi.json", app).exclude(path_regex=r"events$")


def test_no_server_error(api_schema) -> None:
    # Hypothesis over each operation's case strategy (schemathesis's pytest plugin does not load
    # under this pytest); every failing operation is reported, not just the first.
    failures: list[str] = []
    calls: dict[str, int] = {}
    for result in api_schema.get_all_operations():
        operation = result.ok()

        @given(case=operation.as_strategy())
        @settings(
            max_examples=12, deadline=None, database=None, derandomize=True, suppress_health_check=list(HealthCheck)
        )
        def fuzz(case) -> None:
            # fuzz() runs within this iteration, so the loop variable is the one it was built for
            calls[operation.path] = calls.get(operation.path, 0) + 1  # noqa: B023
            case.call_and_validate(checks=[not_a_server_error])

        try:
            fuzz()
        except Exception as exc:  # collect and report all operations' failures together
            failures.append(f"{operation.method.upper()} {operation.path}: {exc}")
    assert not failures, "\n\n".join(failures)
    assert len(calls) >= 8 and min(calls.values()) >= 1, calls  # every path was exercised


def test_fuzzing_covers_the_state_changing_routes(api_schema) -> None:
    paths = {op.path for op in (result.ok() for result in api_schema.get_all_operations())}
    assert {"/api/runs", "/api/runs/{run_id}/stop", "/api/runs/{run_id}/artifacts/{name}"} <= paths, paths
    assert not any(p.endswith("events") for p in paths)
