"""Procedural homes: structure, categories, navigability and determinism (pure data, no PyBullet)."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest
from scipy import ndimage

from agent.types import GOAL_CATEGORIES
from sim.geometry import FootprintIndex
from sim.scene_gen import generate_home
from sim.textures import Material, generate

SEEDS = list(range(12))


@pytest.mark.parametrize("seed", SEEDS)
def test_home_structure(seed: int) -> None:
    home = generate_home(seed)
    assert 3 <= len(home.rooms) <= 8
    kinds = Counter(r.kind for r in home.rooms)
    assert kinds["living room"] == 1 and kinds["bathroom"] >= 1 and kinds["bedroom"] >= 1
    cats = Counter(o.category for o in home.instances)
    assert set(cats) <= set(GOAL_CATEGORIES)
    assert cats["toilet"] == kinds["bathroom"] and cats["bed"] == kinds["bedroom"]
    assert [o.object_id for o in home.objects] == list(range(len(home.objects)))
    assert all(o.is_instance for o in home.objects[: len(home.instances)])
    # every material a part names exists
    for o in home.objects:
        assert all(p.material in home.materials for p in o.parts)


@pytest.mark.parametrize("seed", SEEDS)
def test_every_room_is_reachable(seed: int) -> None:
    home = generate_home(seed)
    index = FootprintIndex(home.solid_footprints(), home.bounds_m)
    grid = index.navigable_grid(0.05)
    labels, _ = ndimage.label(grid.navigable, structure=np.ones((3, 3)))
    sizes = np.bincount(labels.ravel())
    sizes[0] = 0
    main = labels == np.argmax(sizes)
    xs, ys = grid.cell_centres()
    for room in home.rooms:
        x0, y0, x1, y1 = room.rect_m
        inside = (xs > x0) & (xs < x1) & (ys > y0) & (ys < y1)
        assert (main & inside).sum() > 0.2 * inside.sum(), room.name


def test_same_seed_same_home_and_different_seeds_differ() -> None:
    assert generate_home(5) == generate_home(5)
    assert generate_home(5) != generate_home(6)


def test_distractors_share_a_home() -> None:
    # across a few homes, most have two or more instances of some category
    multi = [max(Counter(o.category for o in generate_home(s).instances).values()) >= 2 for s in SEEDS]
    assert sum(multi) >= len(SEEDS) * 0.75


def test_textures_are_deterministic_distinct_and_tile() -> None:
    a = generate(Material("fabric", 11, 0.5))
    assert a.shape == (256, 256, 3) and a.dtype == np.uint8
    assert np.array_equal(a, generate(Material("fabric", 11, 0.5)))
    assert not np.array_equal(a, generate(Material("fabric", 12, 0.5)))
    for fam in ("wood", "leaves", "carpet", "paint"):
        t = generate(Material(fam, 3, 0.5)).astype(float)
        # seamless: the jump across the wrap is like the jump between neighbouring columns
        wrap = np.abs(t[:, 0] - t[:, -1]).mean()
        inner = np.abs(t[:, 1:] - t[:, :-1]).mean()
        assert wrap < 3 * inner + 2, fam


def test_a_style_makes_look_alike_but_different_textures() -> None:
    a = generate(Material("fabric", 1, 0.5, style=42)).astype(float)
    b = generate(Material("fabric", 2, 0.5, style=42)).astype(float)
    c = generate(Material("fabric", 3, 0.5, style=43)).astype(float)
    assert not np.array_equal(a, b)
    # same colours: the mean colour of a set is close, another style's is not
    assert (
        np.abs(a.mean(axis=(0, 1)) - b.mean(axis=(0, 1))).max()
        < np.abs(a.mean(axis=(0, 1)) - c.mean(axis=(0, 1))).max()
    )


def test_dining_chairs_are_a_matching_set() -> None:
    for seed in SEEDS:
        home = generate_home(seed)
        chairs = [o for o in home.instances if o.category == "chair" and home.rooms[o.room_index].kind == "kitchen"]
        if len(chairs) >= 2:
            styles = {
                home.materials[p.material].style
                for o in chairs
                for p in o.parts
                if p.material in home.materials and home.materials[p.material].family == "fabric"
            }
            assert len(styles) == 1 and styles != {-1}
            return
    # A failure, not a skip: a generator that stops making kitchens with two chairs would
    # otherwise leave this test silently untested.
    pytest.fail(f"no kitchen with two chairs among seeds {list(SEEDS)}: the test has nothing to check")
