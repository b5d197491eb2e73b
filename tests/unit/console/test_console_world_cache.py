"""The simulator home kept built between runs (console.sim_adapter.WorldCache)."""

from __future__ import annotations

from console.sim_adapter import WorldCache


class FakeWorld:
    def __init__(self, name: str) -> None:
        self.name = name
        self.closed = False

    def close(self) -> None:
        self.closed = True


def test_same_home_is_reused_another_replaces_it() -> None:
    cache = WorldCache()
    builds: list[str] = []

    def build(name: str):
        builds.append(name)
        return FakeWorld(name)

    a = cache.get(("home", 0, 3), lambda: build("a"))
    assert cache.get(("home", 0, 3), lambda: build("again")) is a and builds == ["a"]
    b = cache.get(("home", 1, 3), lambda: build("b"))
    assert a.closed and not b.closed and builds == ["a", "b"]
    cache.close()
    assert b.closed


def test_warm_up_never_replaces_a_world_in_use() -> None:
    cache = WorldCache()
    in_use = cache.get(("home", 1, 3), lambda: FakeWorld("run"))
    assert cache.warm(("home", 0, 3), lambda: FakeWorld("warm")) is False
    assert not in_use.closed and cache.get(("home", 1, 3), lambda: FakeWorld("x")) is in_use
    empty = WorldCache()
    assert empty.warm(("home", 0, 3), lambda: FakeWorld("warm")) is True
