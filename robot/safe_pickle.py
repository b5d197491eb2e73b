"""Unpickling messages from the network with an allow-list.

stretch_ai's bridge sends every message as one pickled dict (``send_pyobj``). A pickle
can name any importable callable (``os.system`` through ``__reduce__``), so unpickling
what arrives on a socket with ``pickle.loads`` lets whoever can reach the port run code
on the workstation. This unpickler resolves only the globals needed to rebuild numpy
arrays and numpy scalars; plain types (dict, list, tuple, str, bytes, int, float, bool,
None, set) have their own pickle opcodes and need no globals at all.
"""

from __future__ import annotations

import io
import pickle
from typing import Any

import numpy as np

# The robot runs numpy 1.x (``numpy.core``), the workstation may run numpy 2.x
# (``numpy._core``): accept both spellings and map them to this interpreter's objects.
_np_core = np._core if hasattr(np, "_core") else np.core  # type: ignore[attr-defined]

_ALLOWED: dict[tuple[str, str], Any] = {
    ("numpy", "ndarray"): np.ndarray,
    ("numpy", "dtype"): np.dtype,
    # protocol 2-4: ndarray.__reduce__ -> _reconstruct(ndarray, shape, typecode) + setstate
    ("numpy.core.multiarray", "_reconstruct"): _np_core.multiarray._reconstruct,
    ("numpy._core.multiarray", "_reconstruct"): _np_core.multiarray._reconstruct,
    # numpy scalars (np.float64, np.bool_, ...)
    ("numpy.core.multiarray", "scalar"): _np_core.multiarray.scalar,
    ("numpy._core.multiarray", "scalar"): _np_core.multiarray.scalar,
    # protocol 5: contiguous arrays pickle through a PickleBuffer and _frombuffer
    ("numpy.core.numeric", "_frombuffer"): _np_core.numeric._frombuffer,
    ("numpy._core.numeric", "_frombuffer"): _np_core.numeric._frombuffer,
    # protocol 2 stores bytes as _codecs.encode(str, "latin1"): a pure function
    ("_codecs", "encode"): __import__("_codecs").encode,
    ("builtins", "bytearray"): bytearray,
    ("builtins", "complex"): complex,
    ("builtins", "set"): set,
    ("builtins", "frozenset"): frozenset,
}
# Protocol 0-2 pickles spell the builtins module the Python 2 way.
_ALLOWED.update({("__builtin__", name): obj for (module, name), obj in list(_ALLOWED.items()) if module == "builtins"})


class UnsafePickleError(pickle.UnpicklingError):
    """The message names a global outside the allow-list (or is not a valid pickle)."""


class _AllowListUnpickler(pickle.Unpickler):
    def find_class(self, module: str, name: str) -> Any:
        try:
            return _ALLOWED[(module, name)]
        except KeyError:
            raise UnsafePickleError(
                f"refusing to unpickle global {module}.{name}: only numpy arrays and plain types are allowed"
            ) from None

    def persistent_load(self, pid: Any) -> Any:
        raise UnsafePickleError("refusing a pickle with persistent ids")


def safe_loads(data: bytes | bytearray | memoryview) -> Any:
    """Unpickle ``data`` allowing only numpy arrays/scalars and plain Python types.

    Raises ``UnsafePickleError`` for any other global, and for malformed data.
    """
    try:
        return _AllowListUnpickler(io.BytesIO(bytes(data))).load()
    except UnsafePickleError:
        raise
    except (pickle.UnpicklingError, EOFError, ValueError, TypeError, AttributeError, IndexError, KeyError) as exc:
        raise UnsafePickleError(f"malformed pickle: {type(exc).__name__}: {exc}") from exc
