"""Observations and time per step over the stretch_ai bridge protocol, against the fake robot.

The fake robot (a PyBullet home, scene seed 0) builds observations in the bridge's order
(images grabbed, then the pose read, then compression, then the step stamped at send
time, with the base moving throughout). For each client rule it runs a scripted sequence
of actions and prints

* ``stale observations: N of M``: observations whose depth disagrees with a render at the
  pose they report (more than 1% of the valid pixels more than 5 cm off);
* observations whose reported pose is not where the robot stood after the step (images
  and pose both from before the motion ended: not stale by the definition above, still
  wrong for the step);
* medians of ``apply`` (send, the fake's motion at its default speed, echo, arrival check),
  ``observe`` (wait for an observation captured after the acknowledgement, decode) and
  their sum, the time per step.

Rules: ``old`` takes the first observation that echoes the step (the client before
issue 12, ``observations_after_echo=0``); ``new`` the one after it (the default, 1).

    .venv/bin/python benchmarks/bench_stretch_protocol.py [n_steps] [--rule old|new|both] [--slow]
"""

from __future__ import annotations

import argparse
import math
import statistics
import time
from dataclasses import dataclass

import numpy as np

from agent.types import Action, Pose2D
from robot import encoding
from robot.backend import StretchBackend
from robot.config import StretchConfig
from robot.fake_server import FakeKnobs, FakeStretch
from robot.fake_sim import SimFakeWorld

RULES = {"old": 0, "new": 1}
PATTERN = [Action.MOVE_FORWARD, Action.TURN_LEFT, Action.MOVE_FORWARD, Action.TURN_RIGHT, Action.TURN_RIGHT]


@dataclass
class Sample:
    reported_world: Pose2D
    truth_world: Pose2D
    tilt_rad: float
    depth_m: np.ndarray
    apply_s: float
    observe_s: float


def run_rule(world: SimFakeWorld, n_after: int, n_steps: int, knobs: FakeKnobs) -> tuple[list[Sample], float, int]:
    samples: list[Sample] = []
    with FakeStretch(world, obs_port=0, action_port=0, state_port=0, knobs=knobs) as fake:
        obs, act, state = fake.ports
        config = StretchConfig(
            obs_port=obs, action_port=act, state_port=state, connect_timeout_s=30.0, observations_after_echo=n_after
        )
        with StretchBackend(np.zeros((64, 64, 3), np.uint8), config) as backend:
            t0 = time.perf_counter()
            backend.reset()
            reset_s = time.perf_counter() - t0
            start = fake.pose_world
            for k in range(n_steps):
                t0 = time.perf_counter()
                backend.apply(PATTERN[k % len(PATTERN)])
                t1 = time.perf_counter()
                o = backend.observe()
                t2 = time.perf_counter()
                samples.append(
                    Sample(start.compose(o.pose), fake.pose_world, o.camera_tilt_rad, o.depth_m, t1 - t0, t2 - t1)
                )
            blocked = sum(m.blocked for m in backend.moves)
    return samples, reset_s, blocked


def judge(world: SimFakeWorld, samples: list[Sample]) -> tuple[list[float], list[bool]]:
    """Per sample the share of depth pixels > 5 cm off a render at the reported pose; and
    how many reported a pose other than the robot's. Renders run here, after the fake has
    stopped (one thread per PyBullet client)."""
    off, wrong_pose = [], []
    for s in samples:
        _, depth = world.render(s.reported_world, s.tilt_rad)
        valid = (depth > 0) & (s.depth_m > 0)
        off.append(float(np.mean(np.abs(depth - s.depth_m)[valid] > 0.05)) if valid.any() else 0.0)
        yaw_err = abs(math.remainder(s.reported_world.yaw_rad - s.truth_world.yaw_rad, 2 * math.pi))
        wrong_pose.append(s.reported_world.distance_to(s.truth_world) > 1e-3 or yaw_err > math.radians(0.1))
    return off, wrong_pose


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("n_steps", type=int, nargs="?", default=40)
    parser.add_argument("--rule", choices=("old", "new", "both"), default="both")
    parser.add_argument("--slow", action="store_true", help="a real Stretch's pace (0.2 m/s, 0.6 rad/s)")
    args = parser.parse_args()
    world = SimFakeWorld.from_seed(0)
    rgb, depth = world.render(world.start_world, 0.0)
    rgb_enc, depth_enc = encoding.encode_rgb(rgb), encoding.encode_depth(depth)
    decode = []
    for _ in range(20):
        t0 = time.perf_counter()
        encoding.decode_rgb(rgb_enc)
        encoding.decode_depth(depth_enc)
        decode.append(time.perf_counter() - t0)
    med = statistics.median
    print(f"frame: rgb {rgb_enc.nbytes / 1024:.0f} KiB JPEG, depth {depth_enc.nbytes / 1024:.0f} KiB JPEG2000")
    print(f"decode one frame:       median {1000 * med(decode):6.1f} ms")
    rules = ("old", "new") if args.rule == "both" else (args.rule,)
    step_ms = {}
    for rule in rules:
        knobs = FakeKnobs(faithful=True)
        if args.slow:
            knobs.linear_speed_m_s, knobs.angular_speed_rad_s = 0.2, 0.6
        samples, reset_s, blocked = run_rule(world, RULES[rule], args.n_steps, knobs)
        off, wrong_pose = judge(world, samples)
        stale = [f for f in off if f > 0.01]
        step_ms[rule] = 1000 * med(s.apply_s + s.observe_s for s in samples)
        print(
            f"\nrule {rule} (observations_after_echo={RULES[rule]}), faithful fake, {'slow' if args.slow else 'default'} speeds:"
        )
        print(
            f"stale observations: {len(stale)} of {len(samples)}"
            + (
                f" (depth pixels > 5 cm off: median {100 * med(stale):.0f}%, max {100 * max(stale):.0f}%)"
                if stale
                else ""
            )
        )
        print(f"reported pose not the robot's after the step: {sum(wrong_pose)} of {len(samples)}")
        either = sum(f > 0.01 or w for f, w in zip(off, wrong_pose))
        print(f"observations wrong for their step (either): {either} of {len(samples)}")
        print(f"reset (posture, head):  {1000 * reset_s:6.1f} ms")
        print(f"apply (incl. motion):   median {1000 * med(s.apply_s for s in samples):6.1f} ms  ({blocked} blocked)")
        print(f"observe:                median {1000 * med(s.observe_s for s in samples):6.1f} ms")
        print(f"step over the protocol: median {step_ms[rule]:6.1f} ms")
    if len(step_ms) == 2:
        print(
            f"\nextra time per step for provably fresh observations: {step_ms['new'] - step_ms['old']:+.1f} ms (median)"
        )
    world.close()


if __name__ == "__main__":
    main()
