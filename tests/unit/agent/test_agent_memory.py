"""The agent's memory of a home across goals (agent/memory.py, issue 31).

The policy runs here in a box world whose objects are painted in colours, with a matcher that
implements the ``Matcher`` protocol on those colours: keypoints on painted pixels, a descriptor
per keypoint that encodes its colour, matches between keypoints of one colour. So the memory's
path is the real one (descriptors kept as float16, the mutual-nearest gate, the full matcher on
stored features, the stored 3D points) without a learned model."""

from __future__ import annotations

import logging
import math
from dataclasses import replace

import cv2
import numpy as np
import pytest
import skimage.data

from agent.config import AgentConfig, PolicyConfig
from agent.localisation import GoalLocaliser
from agent.memory import HomeMemory, InHomeFrame, MemoryConfig
from agent.modes import Mode
from agent.policy import ModIINAgent
from agent.projection import project_points
from agent.reid import Features, Matches, ReIDConfig, ReIdentifier, make_matcher
from agent.segmentation import SegmentationConfig
from agent.types import Action, AgentRecord, Intrinsics, Observation, Pose2D
from tests.helpers.agent_scenes import BoxWorld, obs_and_ids, observation, room_walls

PALETTE = ((255, 0, 0), (0, 0, 255), (0, 200, 0), (255, 255, 0))  # red, blue, green, yellow


class ColourMatcher:
    """Keypoints on painted pixels (every other pixel), each with a descriptor that is its colour's
    one-hot vector of ``PALETTE``; a goal keypoint matches a frame keypoint of its colour, in
    order, with confidence 1 (the score is the number of matches)."""

    name = "colour"

    def extract(self, rgb: np.ndarray, max_keypoints: int) -> Features:
        xy, desc = [], []
        for c, colour in enumerate(PALETTE):
            vu = np.argwhere(np.all(rgb == colour, axis=2))
            vu = vu[(vu[:, 0] % 2 == 0) & (vu[:, 1] % 2 == 0)]
            xy.append(vu[:, ::-1].astype(np.float32))
            d = np.zeros((len(vu), 8), np.float32)
            d[:, c] = 1.0
            desc.append(d)
        kp, de = np.concatenate(xy)[:max_keypoints], np.concatenate(desc)[:max_keypoints]
        return Features(kp, de, (rgb.shape[1], rgb.shape[0]))

    def match(self, goal: Features, obs: Features) -> Matches:
        if len(goal) == 0 or len(obs) == 0:
            return Matches.empty()
        cg, co = np.argmax(goal.descriptors, axis=1), np.argmax(obs.descriptors, axis=1)
        i0, i1 = [], []
        for c in np.unique(cg):
            g, o = np.flatnonzero(cg == c), np.flatnonzero(co == c)
            n = min(len(g), len(o))
            i0.append(g[:n])
            i1.append(o[:n])
        a, b = np.concatenate(i0), np.concatenate(i1)
        return Matches(a.astype(np.int64), b.astype(np.int64), np.ones(len(a), np.float32))


def goal_image(colour: tuple[int, int, int], side_px: int = 40) -> np.ndarray:
    """A 64 x 64 goal photo: the object a ``side_px`` square of its colour in the middle."""
    img = np.zeros((64, 64, 3), np.uint8)
    lo = 32 - side_px // 2
    img[lo : lo + side_px, lo : lo + side_px] = colour
    return img


class ColourWorld(BoxWorld):
    """A BoxWorld whose objects show in colours, with one goal at a time: ``begin_goal`` keeps the
    robot where it is and restarts the step count, as a multi-goal backend would; its poses stay
    in the first goal's frame (the memory's assumption), or with ``restart_frame`` start again
    from where the robot stands (as the simulator's backend, one per goal, does)."""

    def __init__(self, boxes, start: Pose2D, colours: dict[int, tuple[int, int, int]]) -> None:
        super().__init__(boxes, start, goal_box=next(iter(colours)))
        self.colours = colours
        self.goal_rgb = np.zeros((64, 64, 3), np.uint8)

    def begin_goal(self, box: int, goal_rgb: np.ndarray, restart_frame: bool = False) -> None:
        self.goal_box, self.goal_rgb, self.step = box, goal_rgb, 0
        if restart_frame:
            self.start = self.pose

    def reset(self) -> Observation:
        return self.observe()

    def close(self) -> None:
        pass

    def observe(self) -> Observation:
        obs = super().observe()
        for box, colour in self.colours.items():
            obs.rgb[self._ids == box] = colour
        return replace(obs, goal_image=self.goal_rgb)


def room():
    """One 7 x 4 m room: a red box behind the start (x < 0), a blue one ahead (x > 0), a green one
    in a corner; the robot starts between them facing the blue one."""
    walls = room_walls(-3.0, -2.0, 4.0, 2.0)
    red, blue, green = (-2.4, -0.3, -1.8, 0.3, 0.8), (2.2, -0.3, 2.8, 0.3, 0.8), (3.0, 1.2, 3.6, 1.8, 0.8)
    boxes = walls + [red, blue, green]
    n = len(walls)
    colours = {n: PALETTE[0], n + 1: PALETTE[1], n + 2: PALETTE[2]}
    return ColourWorld(boxes, Pose2D(0.0, 0.0, 0.0), colours), n, n + 1, n + 2


def colour_agent(home: HomeMemory | None, **policy) -> ModIINAgent:
    """tau 100 matches, potential evidence at tau/2, the gate off (its threshold would be the
    xfeat calibration's); the goal mask is the whole goal image."""
    cfg = AgentConfig(
        reid=ReIDConfig(tau=100.0, gate=False),
        policy=PolicyConfig(**{"step_budget": 400, **policy}),
        segmentation=SegmentationConfig(source="oracle"),
        memory=MemoryConfig(),
    )
    return ModIINAgent(
        cfg, matcher=ColourMatcher(), goal_mask_fn=lambda img: np.ones(img.shape[:2], bool), home_memory=home
    )


def run_goal(agent: ModIINAgent, world: ColourWorld | InHomeFrame, max_steps: int = 300) -> list[AgentRecord]:
    """One goal with the loop's order (reset with the first observation's goal image, act, apply),
    to STOP or ``max_steps``."""
    obs = world.observe()
    agent.reset(obs.goal_image)
    out = []
    for _ in range(max_steps):
        action = agent.act(obs)
        assert agent.last_record is not None
        out.append(agent.last_record)
        world.apply(action)
        if action == Action.STOP:
            break
        obs = world.observe()
    return out


def same_records(a: list[AgentRecord], b: list[AgentRecord]) -> None:
    """Field for field, apart from timings (and the map snapshot's arrays, compared by value)."""
    assert len(a) == len(b)
    for x, y in zip(a, b):
        for name in AgentRecord.__dataclass_fields__:
            if name == "timings_ms":
                continue
            u, v = getattr(x, name), getattr(y, name)
            if name == "map":
                assert (u is None) == (v is None)
                if u is not None:
                    for f in ("obstacle", "explored", "visited", "collision", "goal", "frontier", "blacklist"):
                        assert np.array_equal(getattr(u, f), getattr(v, f)), (x.step, f)
                    assert u.origin_xy_m == v.origin_xy_m
            elif isinstance(u, np.ndarray):
                assert np.array_equal(u, v), (x.step, name)
            else:
                assert u == v, (x.step, name, u, v)


# --- the store ------------------------------------------------------------------------------


def _features(n: int, value: float = 1.0) -> Features:
    xy = np.stack([np.arange(n) % 90, np.arange(n) // 90], axis=1).astype(np.float32)
    return Features(xy, np.full((n, 8), value, np.float32), (90, 160))


def _offer(mem: HomeMemory, x: float, y: float, yaw_deg: float, step: int, n: int = 10):
    obs = observation([], Pose2D(x, y, math.radians(yaw_deg)), step=step)
    return mem.offer(obs, _features(n), np.ones((n, 3), np.float32), "colour")


def test_the_memory_keeps_one_keyframe_per_place_and_heading_the_newest():
    mem = HomeMemory(MemoryConfig(cell_m=1.0, heading_bins=8, max_keyframes=10))
    mem.begin_goal(AgentConfig().mapping)
    a = _offer(mem, 0.2, 0.2, 0, 0)
    b = _offer(mem, 0.8, 0.7, 20, 1)  # same square metre, same 45 deg bin: replaces a
    assert a is not None and b is not None and len(mem) == 1 and mem.keyframes == (b,)
    c = _offer(mem, 0.8, 0.7, 40, 2)  # the next heading bin
    d = _offer(mem, 1.2, 0.7, 20, 3)  # the next place
    e = _offer(mem, -0.1, 0.5, 0, 4)  # x < 0 is another square
    assert mem.keyframes == (b, c, d, e)
    # a frame whose keypoints have (almost) no 3D point is not kept
    obs = observation([], Pose2D(3.0, 3.0, 0.0), step=5)
    pts = np.full((10, 3), np.nan, np.float32)
    pts[0] = 1.0
    assert mem.offer(obs, _features(10), pts, "colour") is None and len(mem) == 4
    # another matcher's descriptors do not mix with these (an agent with another matcher is
    # refused at its goal's start)
    with pytest.raises(ValueError, match="colour"):
        mem.offer(obs, _features(10), np.ones((10, 3), np.float32), "sift")
    with pytest.raises(ValueError, match="colour"):
        mem.begin_goal(AgentConfig().mapping, "sift")
    assert mem.goal_index == 0
    # the size is the keyframes' arrays: float16 descriptors, float32 keypoints and points
    assert mem.size_bytes == 4 * (10 * 8 * 2 + 10 * 2 * 4 + 10 * 3 * 4)


def test_the_memory_is_bounded_in_count_and_in_age():
    mem = HomeMemory(MemoryConfig(max_keyframes=3, max_age_goals=1))
    mapping = AgentConfig().mapping
    grid = mem.begin_goal(mapping)  # goal 0
    kfs = [_offer(mem, 2.0 * i, 0.0, 0, i) for i in range(5)]
    assert mem.keyframes == tuple(kfs[2:])  # the oldest went first
    assert mem.begin_goal(mapping) is grid  # goal 1: the same map, goal 0's keyframes still serve
    new = _offer(mem, 0.0, 5.0, 0, 0)
    assert len(mem) == 3 and mem.keyframes[-1] is new and all(k.goal_index == 0 for k in mem.keyframes[:2])
    mem.begin_goal(mapping)  # goal 2: goal 0's keyframes are two goals old
    assert mem.keyframes == (new,) and mem.goal_index == 2
    mem.clear()
    assert len(mem) == 0 and mem.grid is None and mem.goal_index == -1 and mem.goals == []


def test_a_new_goal_keeps_the_maps_geometry_and_explored_area_but_not_the_last_goals_search():
    mem = HomeMemory()
    mapping = AgentConfig().mapping
    grid = mem.begin_goal(mapping)
    obs, _ = obs_and_ids(Pose2D(0.0, 0.0, 0.0))
    grid.update(obs)
    grid.mark_collision(Pose2D(0.0, 0.0, 0.0))
    cells = grid.xy_to_ij(np.array([[3.2, 0.0]]))
    grid.set_goal_cells(cells)
    grid.blacklist_cells(cells, 0.3)
    grid.blacklist_cells(cells, 0.3, layer="potential_blacklist")
    grid.mark_visited((0.0, 0.0), (0.5, 0.0))
    grid.blacklist_disk((1.0, 1.0), 0.5, layer="frontier_blacklist")
    assert grid.layers.explored.any() and grid.layers.frontier_blacklist.any()
    before = {n: getattr(grid.layers, n).copy() for n in ("obstacle", "visited", "collision", "explored")}
    assert mem.begin_goal(mapping) is grid
    L = grid.layers
    assert not (L.goal.any() or L.blacklist.any() or L.potential_blacklist.any())
    # the frontiers the last goal gave up are its own; what it looked over stays (forgotten by
    # the agent when no frontier is left: the test below)
    assert not L.frontier_blacklist.any()
    assert all(np.array_equal(getattr(L, n), v) and v.any() for n, v in before.items())
    with pytest.raises(ValueError, match="mapping config"):
        mem.begin_goal(replace(mapping, resolution_m=0.1))


def test_a_keyframes_points_are_its_keypoints_lifted_from_the_depth_at_them():
    """Each stored point projects back onto its keypoint at the depth read there (the median of
    the 3 x 3 window: on a flat face the depth at the pixel itself), and is the point the localiser lifts
    for a live match of that pixel; keypoints on the floor or without depth have none."""
    obs, ids = obs_and_ids(Pose2D(0.5, 0.2, math.radians(10)))
    loc = GoalLocaliser()
    rng = np.random.default_rng(0)
    uv = np.stack([rng.uniform(2, 88, 300), rng.uniform(2, 158, 300)], axis=1).astype(np.float32)
    pts = loc.keypoint_points(obs, uv)
    ok = np.isfinite(pts).all(axis=1)
    assert pts.shape == (300, 3) and 50 < ok.sum() < 300
    px, z = project_points(pts[ok], obs.intrinsics, obs.pose, obs.camera_height_m)
    assert np.abs(px - uv[ok]).max() < 1e-3
    u, v = np.round(uv[ok, 0]).astype(int), np.round(uv[ok, 1]).astype(int)
    valid = np.where(obs.depth_m > 0, obs.depth_m, np.nan)  # 0: no reading, left out of the median
    window = np.array([np.nanmedian(valid[b - 1 : b + 2, a - 1 : a + 2]) for a, b in zip(u, v)])
    assert np.allclose(z, window, rtol=1e-5)
    at = obs.depth_m[v, u]
    assert np.median(np.abs(z[at > 0] / at[at > 0] - 1.0)) < 1e-5  # on a flat face, the depth at the pixel
    assert np.array_equal(pts[ok], loc.points_from_pixels(obs, uv))  # the same points as a live frame
    # no point on the floor (below the localiser's minimum height), none where the depth is 0
    floor = ids[np.round(uv[:, 1]).astype(int), np.round(uv[:, 0]).astype(int)] < 0
    assert not ok[floor & (pts[:, 2] < 0.02)].any()
    obs0 = replace(obs, depth_m=np.zeros_like(obs.depth_m))
    assert np.isnan(loc.keypoint_points(obs0, uv)).all()


@pytest.mark.parametrize("matcher", ["xfeat_lighterglue", "sift"])
def test_a_remembered_frame_scores_as_the_live_frame_did(matcher):
    """A frame kept as a keyframe (float16 descriptors, no image) scores against a goal as the
    live frame does, with the same matches, through the matcher itself."""
    goal = cv2.resize(skimage.data.astronaut(), (512, 512))
    A = cv2.getRotationMatrix2D((256, 256), 10, 0.8)
    frame = cv2.resize(cv2.warpAffine(goal, A, (512, 512))[60:460, 100:330], (360, 640))
    reid = ReIdentifier(ReIDConfig(matcher=matcher, tau=1.0, num_threads=1, gate=False))
    reid.set_goal(goal)
    live = reid.compare(frame)
    assert live.features is not None and live.score > 20
    k = Intrinsics.from_hfov(360, 640, 42.0)
    obs = Observation(frame, np.full((640, 360), 2.0, np.float32), Pose2D(), k, goal)
    mem = HomeMemory()
    mem.begin_goal(AgentConfig().mapping)
    pts = GoalLocaliser().keypoint_points(obs, live.features.keypoints_xy)
    kf = mem.offer(obs, live.features, pts, reid.matcher.name)
    assert kf is not None
    rec = mem.recall(
        reid.goal, reid.matcher, score_kind="conf", min_cosine=0.82, gate_threshold=None, top_k=8, min_score=0.0
    )
    assert len(rec.scored) == 1 and rec.scored[0][1] > 0  # the gate's count, from the stored descriptors
    ((r,),) = [rec.recollections]
    assert r.score == pytest.approx(live.score, rel=0.03)
    same = np.isin(r.goal_xy[:, 0], live.goal_xy[:, 0])
    assert same.mean() > 0.9
    # a wall 2 m ahead: its keypoints have points, those lifted below the floor (the image's
    # bottom) none
    has = np.isfinite(r.points_xyz).all(axis=1)
    assert 0.5 < has.mean() < 1.0 and (r.points_xyz[has, 0] == pytest.approx(2.0))


def test_the_recall_stops_an_unrelated_keyframe_at_the_exit_layer_and_scores_a_matching_one_in_full():
    """With LighterGlue's exit stage (the gate's second stage) a keyframe of another scene stops
    after the exit layer and scores 0; the keyframe of the goal scores exactly as without it."""
    goal = cv2.resize(skimage.data.astronaut(), (512, 512))
    same = cv2.resize(goal[60:460, 100:330], (360, 640))
    other = cv2.resize(skimage.data.coffee(), (360, 640))
    matcher = make_matcher(ReIDConfig(num_threads=1))  # the default: the exit stage after layer 2
    assert getattr(matcher, "exit_layer", 0) == 2
    k = Intrinsics.from_hfov(360, 640, 42.0)
    mem = HomeMemory()
    mem.begin_goal(AgentConfig().mapping)
    for i, img in enumerate((same, other)):
        obs = Observation(img, np.full((640, 360), 2.0, np.float32), Pose2D(3.0 * i, 0.0, 0.0), k, goal, step=i)
        f = matcher.extract(img, 1024)
        mem.offer(obs, f, GoalLocaliser().keypoint_points(obs, f.keypoints_xy), matcher.name)
    g = matcher.extract(goal, 1024)
    kw = dict(score_kind="conf", min_cosine=0.82, gate_threshold=None, top_k=8, min_score=1.0)
    full = {kid: s for kid, _, s in mem.recall(g, matcher, **kw).scored}  # type: ignore[arg-type]
    gated = {kid: s for kid, _, s in mem.recall(g, matcher, exit_threshold=5.0, **kw).scored}  # type: ignore[arg-type]
    assert full[0] > 20 and full[1] < 5 and gated == {0: full[0], 1: 0.0}


# --- the agent across goals --------------------------------------------------------------------


@pytest.mark.slow  # whole policy runs, two goals
def test_a_goal_seen_before_is_localised_from_memory_and_approached_without_exploring():
    """Goal A (red, behind the start): the look-around sees the blue box first and is kept as
    keyframes. Goal B (blue): scored against the memory at reset, before any new frame, it is a
    confirmed candidate at the blue box, and the robot heads there at once: no look-around, no
    exploring, and it stops at it. Goal B's backend starts its poses again where A ended;
    ``InHomeFrame`` puts them back in A's frame."""
    world, red, blue, _ = room()
    home = HomeMemory()
    world.begin_goal(red, goal_image(PALETTE[0]))
    a = run_goal(colour_agent(home), world)
    assert a[-1].event == "stop_at_goal" and world.distance_to_goal() < 1.0
    assert any(r.mode == "look_around" for r in a)
    assert len(home) >= 2 and home.goals[0].final_event == "stop_at_goal" and home.goals[0].candidates
    assert any("memory" in r.timings_ms for r in a)

    world.begin_goal(blue, goal_image(PALETTE[1]), restart_frame=True)
    assert np.allclose(world.observe().pose.as_tuple(), 0.0)
    framed = InHomeFrame(world, a[-1].pose)  # where A ended (a STOP does not move), in A's frame
    assert np.allclose(framed.observe().pose.as_tuple(), a[-1].pose.as_tuple())
    agent = colour_agent(home)
    agent.reset(framed.reset().goal_image)
    # before the first step: candidates from remembered views (negative view ids), at the blue box
    cands = agent._evaluate(agent.localiser.candidates(agent.grid, agent.tau))
    assert cands and cands[0].state.value == "confirmed"
    assert all(v.step < 0 for v in cands[0].views)
    x0, y0, x1, y1, _ = world.boxes[blue]
    cx, cy = cands[0].cluster.centroid_xy_m
    assert x0 - 0.2 <= cx <= x1 + 0.2 and y0 - 0.2 <= cy <= y1 + 0.2
    assert home.goals[1].recalled_views >= 1 and home.goals[1].recall_best_score >= 100
    # ... and the robot goes there without looking around or exploring, and stops at it
    b = []
    obs = framed.observe()
    for _ in range(200):
        action = agent.act(obs)
        b.append(agent.last_record)
        framed.apply(action)
        if action == Action.STOP:
            break
        obs = framed.observe()
    assert b[0].mode == Mode.APPROACH.value and b[0].candidate_id is not None
    assert {r.mode for r in b} <= {"approach", "stopped"}
    # the reason says the candidate rests on the memory alone until a live frame adds to it
    assert "from_memory" in b[0].context and "memory of the home only" in b[0].reason
    live = [i for i, r in enumerate(b) if "from_memory" not in r.context]
    assert live and all("from_memory" not in r.context for r in b[live[0] :])
    assert b[-1].event == "stop_at_goal" and world.distance_to_goal() < 1.0
    # the map's geometry carried over: the first step of goal B already has goal A's obstacles
    assert b[0].map is not None and b[0].map.obstacle.sum() >= a[-1].map.obstacle.sum()
    assert home.goal_index == 1 and home.summary()["goals"][1]["recalled_views"] >= 1


@pytest.mark.slow  # whole policy runs, two goals
def test_a_weaker_remembered_view_gives_a_potential_candidate_verified_by_approach():
    """Goal B's photo shows fewer keypoints than tau: the remembered views score between tau/2
    and tau, so the candidate is potential and the robot verifies it by approach (live views
    from the verify ring confirm it) rather than stopping on memory alone."""
    world, red, blue, _ = room()
    home = HomeMemory()
    world.begin_goal(red, goal_image(PALETTE[0]))
    run_goal(colour_agent(home), world)
    world.begin_goal(blue, goal_image(PALETTE[1], side_px=16))  # 64 keypoints: potential at best
    b = run_goal(colour_agent(home), world)
    assert 50 <= home.goals[1].recall_best_score < 100
    assert b[0].mode == Mode.VERIFY.value and b[0].candidates[0].state == "potential"
    assert "look_around" not in {r.mode for r in b} and "explore" not in {r.mode for r in b}


@pytest.mark.slow  # whole policy runs, two goals
def test_a_goal_memory_has_nothing_for_looks_around_as_without_memory():
    """Goal B (a yellow object, never seen during goal A's search) gets nothing from memory: it
    starts with the look-around, in the remembered map."""
    world, red, _, green = room()
    home = HomeMemory()
    world.begin_goal(red, goal_image(PALETTE[0]))
    run_goal(colour_agent(home, look_around_turns=0), world)
    world.begin_goal(green, goal_image(PALETTE[3]))  # yellow: nothing in the home
    b = run_goal(colour_agent(home), world, max_steps=3)
    assert home.goals[1].recalled_views == 0
    assert [r.mode for r in b] == ["look_around"] * 3


@pytest.mark.slow  # whole policy runs, two goals
def test_the_explored_area_of_earlier_goals_is_forgotten_once_when_no_frontier_is_left(caplog):
    """Goal A (red) looks the room over. Goal B (yellow: nothing in the home) starts in A's
    explored area; with the room looked over there is no frontier, and at the first rescan the
    carried area is forgotten, once: B then explores the room again for itself, and at its later
    rescans keeps what it looked over."""
    world, red, _, green = room()
    home = HomeMemory()
    world.begin_goal(red, goal_image(PALETTE[0]))
    run_goal(colour_agent(home), world)
    carried = int(home.grid.layers.explored.sum())
    assert carried > 0
    world.begin_goal(green, goal_image(PALETTE[3]))
    agent = colour_agent(home, look_around_turns=4, max_rescans=2, last_resort=False)
    obs = world.observe()
    agent.reset(obs.goal_image)
    assert int(agent.grid.layers.explored.sum()) == carried  # B starts in A's explored area
    explored, modes = [], []
    with caplog.at_level(logging.INFO, logger="agent.policy"):
        for _ in range(300):
            action = agent.act(obs)
            modes.append(agent.last_record.mode)
            explored.append(int(agent.grid.layers.explored.sum()))
            world.apply(action)
            if action == Action.STOP:
                break
            obs = world.observe()
    assert modes[-1] == "exhausted"
    first = modes.index("rescan")
    assert explored[first] == 0 and all(e > 0 for e in explored[:first])  # forgotten there ...
    starts = [i for i in range(1, len(modes)) if modes[i] == "rescan" and modes[i - 1] != "rescan"]
    assert len(starts) == 2 and starts[0] == first
    assert explored[starts[1]] > 0  # ... and only once: the second rescan keeps B's own area
    assert "explore" in modes[first:]  # B explored the room again for itself
    assert sum("forgot the explored area" in r.getMessage() for r in caplog.records) == 1


@pytest.mark.slow  # whole policy runs, two goals
def test_memory_dropped_or_empty_is_the_agent_without_memory():
    """Two identical worlds, the same two goals: with a memory cleared between the goals the
    second goal's records are those of an agent without memory, field for field apart from
    timings; and the first goal's records with an empty memory are those without one."""
    w_mem, red, blue, _ = room()
    w_off, *_ = room()
    home = HomeMemory()
    for w in (w_mem, w_off):
        w.begin_goal(red, goal_image(PALETTE[0]))
    a_mem = run_goal(colour_agent(home), w_mem)
    a_off = run_goal(colour_agent(None), w_off)
    same_records(a_mem, a_off)
    assert len(home) > 0
    home.clear()
    for w in (w_mem, w_off):
        w.begin_goal(blue, goal_image(PALETTE[1]))
    b_mem = run_goal(colour_agent(home), w_mem)
    b_off = run_goal(colour_agent(None), w_off)
    same_records(b_mem, b_off)
    assert b_off[0].mode == "look_around" and "memory" not in b_off[0].timings_ms


@pytest.mark.slow  # whole policy runs, two goals
def test_a_goal_whose_poses_start_again_is_logged(caplog):
    """A backend that starts its poses again at the next goal, not put back in the memory's frame
    (``InHomeFrame``): the first pose is far from where the last goal ended, and that is logged."""
    world, red, blue, _ = room()
    home = HomeMemory()
    world.begin_goal(red, goal_image(PALETTE[0]))
    a = run_goal(colour_agent(home), world)
    assert math.hypot(a[-1].pose.x_m, a[-1].pose.y_m) > 1.0
    world.begin_goal(blue, goal_image(PALETTE[1]), restart_frame=True)
    with caplog.at_level("WARNING", logger="agent.memory"):
        run_goal(colour_agent(home), world, max_steps=1)
    assert "same frame" in caplog.text
