"""Time per step over the stretch_ai bridge protocol, against the fake robot on loopback.

Prints medians of: decode (JPEG + JPEG2000 of one 360x640 frame), ``apply`` (send, the
fake's motion at its default speed, echo, arrival check), ``observe`` (wait for a fresh
observation, decode, build) and their sum, over a scripted sequence of actions in a
PyBullet home (scene seed 0).

    .venv/bin/python benchmarks/bench_stretch_protocol.py [n_steps]
"""

from __future__ import annotations

import statistics
import sys
import time

import numpy as np

from agent.types import Action
from robot import encoding
from robot.backend import StretchBackend
from robot.config import StretchConfig
from robot.fake_server import FakeStretch
from robot.fake_sim import SimFakeWorld


def main(n_steps: int = 40) -> None:
    world = SimFakeWorld.from_seed(0)
    rgb, depth = world.render(world.start_world, 0.0)
    rgb_enc, depth_enc = encoding.encode_rgb(rgb), encoding.encode_depth(depth)
    decode = []
    for _ in range(20):
        t0 = time.perf_counter()
        encoding.decode_rgb(rgb_enc)
        encoding.decode_depth(depth_enc)
        decode.append(time.perf_counter() - t0)
    pattern = [Action.MOVE_FORWARD, Action.TURN_LEFT, Action.MOVE_FORWARD, Action.TURN_RIGHT, Action.TURN_RIGHT]
    apply_s, observe_s = [], []
    with FakeStretch(world, obs_port=0, action_port=0, state_port=0) as fake:
        obs, act, state = fake.ports
        with StretchBackend(np.zeros((64, 64, 3), np.uint8), StretchConfig(obs_port=obs, action_port=act, state_port=state)) as backend:
            t0 = time.perf_counter()
            backend.reset()
            reset_s = time.perf_counter() - t0
            for k in range(n_steps):
                t0 = time.perf_counter()
                backend.apply(pattern[k % len(pattern)])
                t1 = time.perf_counter()
                backend.observe()
                apply_s.append(t1 - t0)
                observe_s.append(time.perf_counter() - t1)
            blocked = sum(m.blocked for m in backend.moves)
    world.close()
    med = statistics.median
    print(f"frame: rgb {rgb_enc.nbytes / 1024:.0f} KiB JPEG, depth {depth_enc.nbytes / 1024:.0f} KiB JPEG2000")
    print(f"decode one frame:       median {1000 * med(decode):6.1f} ms")
    print(f"reset (posture, head):  {1000 * reset_s:6.1f} ms")
    print(f"apply (incl. motion):   median {1000 * med(apply_s):6.1f} ms  over {n_steps} steps ({blocked} blocked)")
    print(f"observe:                median {1000 * med(observe_s):6.1f} ms")
    print(f"step over the protocol: median {1000 * med(a + o for a, o in zip(apply_s, observe_s)):6.1f} ms")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 40)
