"""Shared helpers for the interop scripts called by tests/interop.rs.

Values cross the Rust/Python boundary as JSON in which every float64 is written as the
string "f64:<16 hex digits>" (its big-endian IEEE-754 bit pattern), so that comparisons are
exact, -0.0 differs from 0.0 and infinities survive JSON. Integers and strings stay native.
"""

from __future__ import annotations

import json
import struct
import sys
from typing import Any, NoReturn

import numpy as np

F64_PREFIX = 'f64:'


class Mismatch(Exception):
    """A check against an independent implementation failed."""


def fail(msg: str) -> NoReturn:
    print(f'INTEROP FAILURE: {msg}', file=sys.stderr)
    sys.exit(1)


def run_main(main) -> None:
    """Run `main()`, turning any exception into a clear message and exit code 1."""
    try:
        main()
    except Mismatch as err:
        fail(str(err))
    except SystemExit:
        raise
    except BaseException as err:  # noqa: BLE001 - report everything, never a bare traceback only
        import traceback

        traceback.print_exc(file=sys.stderr)
        fail(f'{type(err).__name__}: {err}')


def f64_to_tag(x: float) -> str:
    return F64_PREFIX + struct.pack('>d', float(x)).hex()


def tag_to_f64(s: str) -> float:
    return struct.unpack('>d', bytes.fromhex(s[len(F64_PREFIX):]))[0]


def is_f64_tag(v: Any) -> bool:
    return isinstance(v, str) and v.startswith(F64_PREFIX) and len(v) == len(F64_PREFIX) + 16


def tagged(v: Any) -> Any:
    """Plain Python value (floats, ints, strings, lists, dicts, numpy) -> tagged JSON value."""
    if isinstance(v, bool):
        return v
    if isinstance(v, (float, np.floating)):
        return f64_to_tag(float(v))
    if isinstance(v, (int, np.integer)):
        return int(v)
    if isinstance(v, np.ndarray):
        return [tagged(x) for x in v.tolist()]
    if isinstance(v, (list, tuple)):
        return [tagged(x) for x in v]
    if isinstance(v, dict):
        return {k: tagged(x) for k, x in v.items()}
    if isinstance(v, (bytes, bytearray)):
        return list(v)
    return v


def untagged(v: Any) -> Any:
    """Tagged JSON value -> plain Python value (floats restored bit-exactly)."""
    if is_f64_tag(v):
        return tag_to_f64(v)
    if isinstance(v, list):
        return [untagged(x) for x in v]
    if isinstance(v, dict):
        return {k: untagged(x) for k, x in v.items()}
    return v


def rosbags_to_plain(msg: Any, typestore: Any, typename: str) -> dict:
    """A rosbags message object -> dict of its fields (no constants), recursively."""
    _, fields = typestore.fielddefs[typename]
    out = {}
    for name, (nodetype, detail) in fields:
        out[name] = _rosbags_field_to_plain(getattr(msg, name), typestore, int(nodetype), detail)
    return out


def _rosbags_field_to_plain(val: Any, typestore: Any, nodetype: int, detail: Any) -> Any:
    if nodetype == 1:  # BASE
        # rosbags 0.11.9 treats ROS `byte` as a signed int8 (struct 'b'); ROS 2 maps it to
        # octet, 0..255, as mcap_ros2 and imu-fsda do. Same byte on the wire either way.
        return val & 0xFF if detail[0] == 'byte' else val
    if nodetype == 2:  # NAME
        return rosbags_to_plain(val, typestore, detail)
    # ARRAY (3) or SEQUENCE (4): detail = ((subtype, subdetail), bound)
    (subtype, subdetail), _ = detail
    if isinstance(val, np.ndarray):
        return val.tolist()
    return [_rosbags_field_to_plain(x, typestore, int(subtype), subdetail) for x in val]


def plain_to_rosbags(value: dict, typestore: Any, typename: str) -> Any:
    """A dict of field values -> a rosbags message object of `typename`, recursively."""
    _, fields = typestore.fielddefs[typename]
    names = {n for n, _ in fields}
    if set(value) != names:
        raise Mismatch(f'{typename}: fields {sorted(value)} != rosbags fields {sorted(names)}')
    kwargs = {}
    for name, (nodetype, detail) in fields:
        kwargs[name] = _plain_field_to_rosbags(value[name], typestore, int(nodetype), detail)
    return typestore.types[typename](**kwargs)


_NUMPY_DTYPES = {
    'bool': np.bool_, 'byte': np.uint8, 'char': np.uint8, 'int8': np.int8, 'uint8': np.uint8,
    'int16': np.int16, 'uint16': np.uint16, 'int32': np.int32, 'uint32': np.uint32,
    'int64': np.int64, 'uint64': np.uint64, 'float32': np.float32, 'float64': np.float64,
}


def _plain_field_to_rosbags(val: Any, typestore: Any, nodetype: int, detail: Any) -> Any:
    if nodetype == 1:
        return val - 256 if detail[0] == 'byte' and val > 127 else val
    if nodetype == 2:
        return plain_to_rosbags(val, typestore, detail)
    (subtype, subdetail), _ = detail
    if int(subtype) == 1 and subdetail[0] in _NUMPY_DTYPES:
        return np.array(val, dtype=_NUMPY_DTYPES[subdetail[0]])
    return [_plain_field_to_rosbags(x, typestore, int(subtype), subdetail) for x in val]


def slots_to_plain(obj: Any) -> Any:
    """An mcap_ros2 decoded object (a class with __slots__) -> dict, recursively."""
    if isinstance(obj, (list, tuple)):
        return [slots_to_plain(x) for x in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    slots = getattr(type(obj), '__slots__', None)
    if slots is None:
        return obj
    return {name: slots_to_plain(getattr(obj, name)) for name in slots}


def dump(obj: Any) -> None:
    json.dump(obj, sys.stdout, indent=None, separators=(',', ':'), allow_nan=False)
    sys.stdout.write('\n')
