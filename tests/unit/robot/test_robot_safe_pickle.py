"""The allow-list unpickler: robot messages load, code-running pickles are refused."""

from __future__ import annotations

import pickle
import subprocess

import numpy as np
import pytest

from robot.safe_pickle import UnsafePickleError, safe_loads
from tests.helpers.pickles import RunsShell


def _robot_like_message() -> dict:
    return {
        "rgb": np.arange(100, dtype=np.uint8),
        "camera_K": np.eye(3, dtype=np.float32),
        "camera_pose": np.eye(4),
        "gps": np.array([1.0, 2.0]),
        "compass": np.array([0.5]),
        "step": 7,
        "at_goal": np.bool_(True),
        "scalar": np.float64(1.25),
        "control_mode": "navigation",
        "lidar_points": None,
        "nested": {"tuple": (1, 2.5, "x"), "list": [b"bytes", bytearray(b"ba")], "set": {1, 2}},
        "fortran": np.asfortranarray(np.arange(12.0).reshape(3, 4)),
        "strings": np.array(["a", "bc"]),
    }


@pytest.mark.parametrize("protocol", [2, 3, 4, 5])
def test_robot_messages_round_trip_under_every_protocol(protocol: int) -> None:
    msg = _robot_like_message()
    out = safe_loads(pickle.dumps(msg, protocol=protocol))
    assert out.keys() == msg.keys()
    for key, value in msg.items():
        if isinstance(value, np.ndarray):
            assert out[key].dtype == value.dtype and np.array_equal(out[key], value)
        else:
            assert out[key] == value


class _Popen:
    def __reduce__(self):
        return (subprocess.Popen, (["true"],))


class _Eval:
    def __reduce__(self):
        return (eval, ("__import__('os').getpid()",))


@pytest.mark.parametrize("protocol", [2, 4, 5])
def test_a_pickle_that_runs_a_shell_command_is_refused_and_nothing_runs(tmp_path, protocol: int) -> None:
    marker = tmp_path / "pwned"
    data = pickle.dumps({"rgb": np.zeros(3), "evil": RunsShell(str(marker))}, protocol=protocol)
    with pytest.raises(UnsafePickleError, match="system"):
        safe_loads(data)
    assert not marker.exists()


@pytest.mark.parametrize("payload", [_Popen(), _Eval()])
def test_other_code_running_globals_are_refused(payload) -> None:
    with pytest.raises(UnsafePickleError, match="refusing to unpickle global"):
        safe_loads(pickle.dumps(payload, protocol=4))


def test_a_hand_written_global_opcode_is_refused() -> None:
    # GLOBAL 'posix system', MARK, string, TUPLE, REDUCE -- no Python class needed to build it
    data = b"cposix\nsystem\n(S'true'\ntR."
    with pytest.raises(UnsafePickleError, match="posix.system"):
        safe_loads(data)


def test_garbage_is_a_clear_error() -> None:
    with pytest.raises(UnsafePickleError, match="malformed"):
        safe_loads(b"\x80\x04not a pickle")
    with pytest.raises(UnsafePickleError):
        safe_loads(b"")
