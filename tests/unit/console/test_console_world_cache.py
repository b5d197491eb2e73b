"""What the console keeps between simulator runs (console.sim_cache.WorldCache): the home, and data derived from it."""

from __future__ import annotations

from console.sim_cache import WorldCache


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


def test_derived_data_is_kept_for_its_world_only() -> None:
    cache = WorldCache()
    built: list[str] = []

    def build(name: str):
        built.append(name)
        return object()

    cache.get(("home", 0, 3), lambda: FakeWorld("a"))
    first = cache.derived(("home", 0, 3), "scoring", (5, "c0"), lambda: build("s5"))
    assert cache.derived(("home", 0, 3), "scoring", (5, "c0"), lambda: build("again")) is first
    other = cache.derived(("home", 0, 3), "scoring", (6, "c0"), lambda: build("s6"))  # another target
    assert other is not first and built == ["s5", "s6"]
    # another home replaces the world: what was computed from the old one is gone
    cache.get(("home", 1, 3), lambda: FakeWorld("b"))
    assert cache.derived_items("scoring") == []
    again = cache.derived(("home", 1, 3), "scoring", (5, "c0"), lambda: build("s5 in home 1"))
    assert again is not first and built[-1] == "s5 in home 1"
    # asked for a world that is no longer kept: built, never kept (it would be stale)
    stale = cache.derived(("home", 0, 3), "scoring", (5, "c0"), lambda: build("s5 of a closed world"))
    assert stale is not first and cache.derived_items("scoring") == [(5, "c0")]
    cache.close()
    assert cache.derived_items("scoring") == [] and cache.key is None


def test_derived_data_is_bounded_least_recently_used_first() -> None:
    from console.sim_cache import DERIVED_LIMITS

    cache = WorldCache()
    cache.get(("home", 0, 3), lambda: FakeWorld("a"))
    limit = DERIVED_LIMITS["start_render"]
    for k in range(limit):
        cache.derived(("home", 0, 3), "start_render", k, lambda: object())
    cache.derived(("home", 0, 3), "start_render", 0, lambda: object())  # used again: now the newest
    cache.derived(("home", 0, 3), "start_render", "new", lambda: object())
    items = cache.derived_items("start_render")
    assert len(items) == limit and 1 not in items and items[-2:] == [0, "new"]


def test_the_warm_up_world_starts_without_derived_data() -> None:
    cache = WorldCache()
    assert cache.warm(("home", 0, 3), lambda: FakeWorld("warm"))
    assert cache.derived_items("scoring") == [] and cache.key == ("home", 0, 3)
