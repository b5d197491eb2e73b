"""The console builds one matcher per process and shares it between runs."""

import warnings

import numpy as np

from console import agents


def test_runs_share_one_matcher_and_warm_up_builds_it():
    agents._matchers.clear()
    seconds = agents.warm_up("sim")
    assert seconds > 0
    assert len(agents._matchers) == 1
    warmed = next(iter(agents._matchers.values()))
    first, config = agents.build_agent("sim")
    second, _ = agents.build_agent("stretch")  # same matcher settings: same weights in memory
    assert first.reid.matcher is warmed and second.reid.matcher is warmed
    assert first is not second
    assert config["deployment"] == "sim" and config["tau_resolved"] == first.tau


def test_shared_matcher_accepts_read_only_images():
    agents._matchers.clear()
    agent, _ = agents.build_agent("sim")
    image = np.zeros((64, 48, 3), np.uint8)
    image[10:30, 10:30] = 255
    image.setflags(write=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # torch warns about non-writable arrays
        features = agent.reid.matcher.extract(image, 64)
    assert features.keypoints_xy.shape[1] == 2


def test_a_different_matcher_setting_gets_a_matcher_of_its_own():
    from agent.reid import ReIDConfig

    agents._matchers.clear()
    full = agents.shared_matcher(ReIDConfig(num_threads=1))
    strict = agents.shared_matcher(ReIDConfig(num_threads=1, min_confidence=0.2))
    assert strict is not full and agents.shared_matcher(ReIDConfig(num_threads=1)) is full
    assert strict.min_confidence == 0.2 and full.min_confidence == 0.1
