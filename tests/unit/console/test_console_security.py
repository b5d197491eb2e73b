"""Token and bind-address rules."""

from __future__ import annotations

from console.context import ConsoleConfig
from console.security import is_loopback, token_matches


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
