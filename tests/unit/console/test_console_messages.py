"""Messages an operator reads: sizes and numbers said so that a person can read them (issue 33)."""

from __future__ import annotations

import pytest

from console.photos import PhotoError, PhotoLimits, decode_photo
from console.words import size_words


def test_sizes_in_words() -> None:
    assert size_words(25 * 2**20) == "25 MB" and size_words(20_000) == "20 kB" and size_words(100) == "100 bytes"
    assert size_words(1536) == "1.5 kB"


def test_a_photo_over_the_limit_says_the_limit_in_mb() -> None:
    limits = PhotoLimits()
    with pytest.raises(PhotoError) as caught:
        decode_photo(b"\0" * (limits.max_bytes + 1), limits)  # the API reads one byte past the limit
    assert caught.value.status == 413
    assert "25 MB" in str(caught.value) and "26214401" not in str(caught.value)


def test_a_huge_custom_start_is_not_echoed_digit_by_digit() -> None:
    from console.sim_provider import _parse_start

    class Home:
        id = "home-0"
        starts = ()

    start = _parse_start(Home(), "1e308,-1e308,0")  # type: ignore[arg-type]
    assert start.label == "(1e+308, -1e+308, 0 deg)"
    assert _parse_start(Home(), "1.234,2,90").label == "(1.23, 2.00, 90 deg)"  # type: ignore[arg-type]


def test_a_request_over_the_limit_says_sizes_in_mb() -> None:
    import asyncio
    import json

    from console.security import GuardMiddleware

    async def app(scope, receive, send) -> None:  # never reached: the declared length is refused first
        raise AssertionError("the app was called")

    sent: list[dict] = []

    async def send(message) -> None:
        sent.append(message)

    async def receive() -> dict:
        return {"type": "http.request", "body": b"", "more_body": False}

    guard = GuardMiddleware(app, max_bytes=26 * 2**20)
    scope = {"type": "http", "method": "POST", "headers": [(b"host", b"127.0.0.1"), (b"content-length", b"31457280")]}
    asyncio.run(guard(scope, receive, send))
    assert sent[0]["status"] == 413
    message = json.loads(sent[1]["body"])["detail"]["message"]
    assert message == "the request is 30 MB; the limit is 26 MB", message
