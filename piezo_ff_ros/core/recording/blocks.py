"""Sample blocks ↔ ``sensor_msgs/msg/PointCloud2`` fields, without ROS.

The topic contract (docs/topics.md) carries a block of N samples × k axes as a PointCloud2 "table":
``height = 1``, ``width = N``, one little-endian FLOAT64 field per axis (named by the axis, offsets 0, 8, …),
``point_step = 8·k``, ``row_step = point_step·N``, ``data`` = the [N, k] float64 block row-major, and
``header.stamp`` = the time of the block's FIRST sample.  Stamps are integer nanoseconds on a grid of
``dt_ns = round(1e9 / fs)`` (50 000 ns at 20 kHz), so sample ``k`` of a run has stamp ``t0_ns + k·dt_ns`` and the
sample index of every block is exact.

This module never imports rclpy.  It offers:

- :func:`encode_block` / :func:`decode_block`: block ↔ a plain ``dict`` of PointCloud2 fields (the nodes turn that
  dict into the real ``sensor_msgs.msg.PointCloud2``; :func:`decode_block` also accepts any message-like object
  with the same attributes: an rclpy message, a ``rosbags`` or ``mcap_ros2`` decoded message);
- :func:`serialize_block` / :func:`deserialize_block`: block ↔ CDR bytes (with the 4-byte encapsulation header, as
  on the wire and in MCAP), via the ``rosbags`` type store, so that recordings can be written and read without ROS;
- :func:`serialize_message` / :func:`deserialize_message`: the same for any standard message given as nested dicts
  (``std_msgs/msg/String``, ``diagnostic_msgs/msg/DiagnosticArray`` …);
- stamp ↔ sample-index helpers (:func:`sample_period_ns`, :func:`stamp_for_index`, :func:`index_for_stamp`,
  :func:`check_stamp`).

This is the one codec of the package: the nodes (``nodes/common.py`` delegates here), the recorder and the readers
decode with :func:`decode_block` and get the same verdicts — a field ``count`` other than 1, fields whose offsets are
not ``0, 8, …`` in their listed order, fields that do not name the expected axes, a width of 0 or more than
:data:`MAX_BLOCK_SAMPLES` (checked before the data is touched) are refused; with ``period_ns`` a stamp off the
absolute sample grid is refused, with ``finite`` a NaN/Inf value.  :func:`sample_period_ns` is the one sample-period
function: a rate whose period is not a whole number of nanoseconds is refused.
"""
from __future__ import annotations

from functools import lru_cache
from typing import TYPE_CHECKING, Any, Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike

from ..units import sample_period_ns

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

__all__ = [
    "BLOCK_TYPE", "FRAME_ID", "FLOAT64", "MAX_BLOCK_SAMPLES", "BlockFormatError", "sample_period_ns", "check_stamp", "stamp_for_index", "index_for_stamp",
    "stamp_to_ns", "ns_to_stamp", "encode_block", "decode_block", "block_axes", "serialize_block",
    "deserialize_block", "serialize_message", "deserialize_message", "typestore", "peek_block_samples",
]

BLOCK_TYPE = "sensor_msgs/msg/PointCloud2"  #: message type of the reference/voltage/displacement topics
FRAME_ID = "piezo"  #: header.frame_id of every block
FLOAT64 = 8  #: sensor_msgs/PointField.FLOAT64
_NS = 1_000_000_000
#: the most samples one block message may carry (docs/topics.md): 1 s at 20 kHz, 320 kB for 2 axes; a larger block
#: is refused before its data is read (the driver's ``max_block`` default is the same)
MAX_BLOCK_SAMPLES = 20_000


class BlockFormatError(ValueError):
    """A block message that does not follow the contract (the text starts with the field that is wrong)."""


# ----------------------------------------------------------------------------------------------------------------
# stamps ↔ sample indices (integer nanoseconds, exact)

def check_stamp(stamp_ns: int, period_ns: int) -> int:
    """``stamp_ns`` if it lies on the absolute sample grid (a whole multiple of ``period_ns``), else
    :class:`BlockFormatError`.

    Every stamp of the contract is ``t0 + k·dt_ns`` with ``t0`` itself on the grid (the trajectory node and the
    held point floor their origin to it), so a stamp that is not a multiple of ``dt_ns`` cannot be placed.
    """
    r = int(stamp_ns) % int(period_ns)
    if r:
        raise BlockFormatError(f"block.header.stamp: {int(stamp_ns)} ns is off the {int(period_ns)} ns sample grid "
                               f"(by {r} ns)")
    return int(stamp_ns)


def stamp_for_index(k: int, t0_ns: int, dt_ns: int) -> int:
    """Stamp [ns] of sample ``k``: ``t0_ns + k·dt_ns`` (exact integer arithmetic)."""
    return int(t0_ns) + int(k) * int(dt_ns)


def index_for_stamp(stamp_ns: int, t0_ns: int, dt_ns: int, *, strict: bool = True) -> int:
    """Sample index of ``stamp_ns``: ``(stamp_ns − t0_ns) / dt_ns``.

    With ``strict`` (default) a stamp off the sample grid raises ``ValueError``; otherwise the nearest index is
    returned.
    """
    q, r = divmod(int(stamp_ns) - int(t0_ns), int(dt_ns))
    if r:
        if strict:
            raise ValueError(f"stamp {stamp_ns} ns is not on the sample grid t0={t0_ns} ns + k·{dt_ns} ns "
                             f"(off by {r} ns)")
        if 2 * r >= dt_ns:
            q += 1
    return int(q)


def stamp_to_ns(stamp: Any) -> int:
    """``builtin_interfaces/Time`` (dict or object with ``sec``/``nanosec``) → integer nanoseconds."""
    if isinstance(stamp, Mapping):
        return int(stamp["sec"]) * _NS + int(stamp["nanosec"])
    return int(stamp.sec) * _NS + int(stamp.nanosec)


def ns_to_stamp(stamp_ns: int) -> dict[str, int]:
    """Integer nanoseconds → ``{"sec": …, "nanosec": …}`` (``nanosec`` in [0, 1e9), as ROS requires)."""
    sec, nanosec = divmod(int(stamp_ns), _NS)
    if not -2**31 <= sec < 2**31:
        raise ValueError(f"stamp {stamp_ns} ns does not fit builtin_interfaces/Time (int32 seconds)")
    return {"sec": sec, "nanosec": nanosec}


# ----------------------------------------------------------------------------------------------------------------
# block ↔ PointCloud2 fields (plain Python)

def _as_block(block: ArrayLike, n_axes: int | None = None) -> np.ndarray:
    arr = np.asarray(block, dtype=np.float64)
    if arr.ndim == 1 and n_axes == 1:
        arr = arr[:, None]
    if arr.ndim != 2:
        raise ValueError(f"block: expected a 2-D [N, axes] array, got shape {arr.shape}")
    if n_axes is not None and arr.shape[1] != n_axes:
        raise ValueError(f"block: expected {n_axes} columns (one per axis), got shape {arr.shape}")
    return arr


def encode_block(block: ArrayLike, stamp_ns: int, axes: Sequence[str] = ("x", "y"),
                 frame_id: str = FRAME_ID) -> dict[str, Any]:
    """Block [N, axes] (float64, SI) → the fields of a ``sensor_msgs/msg/PointCloud2``, as plain Python.

    Returns ``{"header": {"stamp": {"sec", "nanosec"}, "frame_id"}, "height": 1, "width": N,
    "fields": [{"name", "offset", "datatype": 8, "count": 1}, …], "is_bigendian": False, "point_step": 8·k,
    "row_step": 8·k·N, "data": bytes, "is_dense": True}``.
    """
    axes = tuple(str(a) for a in axes)
    if not axes or len(set(axes)) != len(axes):
        raise ValueError(f"axes: need distinct axis names, got {axes!r}")
    arr = _as_block(block, len(axes))
    point_step = 8 * len(axes)
    data = np.ascontiguousarray(arr, dtype="<f8").tobytes()
    return {
        "header": {"stamp": ns_to_stamp(stamp_ns), "frame_id": frame_id},
        "height": 1,
        "width": int(arr.shape[0]),
        "fields": [{"name": a, "offset": 8 * i, "datatype": FLOAT64, "count": 1} for i, a in enumerate(axes)],
        "is_bigendian": False,
        "point_step": point_step,
        "row_step": point_step * int(arr.shape[0]),
        "data": data,
        "is_dense": True,
    }


def _get(msg: Any, name: str) -> Any:
    if isinstance(msg, Mapping):
        return msg[name]
    return getattr(msg, name)


def block_axes(msg: Any) -> tuple[str, ...]:
    """Axis names of a block message (its field names, in offset order)."""
    fields = sorted(_get(msg, "fields"), key=lambda f: int(_get(f, "offset")))
    return tuple(str(_get(f, "name")) for f in fields)


def _data_bytes(data: Any) -> bytes | bytearray | memoryview | np.ndarray:
    if isinstance(data, (bytes, bytearray, memoryview)):
        return data
    if isinstance(data, np.ndarray):
        return data
    # rclpy gives array.array('B') or a list of ints
    try:
        return memoryview(data)
    except TypeError:
        return bytes(data)


def decode_block(msg: Any, axes: Sequence[str] | None = None, *, period_ns: int | None = None,
                 finite: bool = False, max_samples: int = MAX_BLOCK_SAMPLES) -> tuple[int, np.ndarray]:
    """PointCloud2 of the contract (dict or message-like) → ``(stamp_ns, block[N, axes])`` (float64, a copy).

    Parameters
    ----------
    msg : Mapping or message-like
        The message (a dict of :func:`encode_block`, an rclpy, ``rosbags`` or ``mcap_ros2`` message).
    axes : sequence of str, optional
        Wanted columns by field name, in that order (default: all fields in offset order).  With ``axes`` the
        fields must name exactly these axes (an unknown or missing one is refused).
    period_ns : int, optional
        The sample period: a stamp off the absolute grid is refused (:func:`check_stamp`).
    finite : bool
        Refuse a NaN/Inf value (what a node that applies the block needs).
    max_samples : int
        Largest width accepted; checked before the data is read.

    Returns
    -------
    (int, numpy.ndarray)
        The stamp of the first sample [ns] and the block.

    Raises
    ------
    BlockFormatError
        (a ``ValueError``) starting with the field that breaks the contract: not FLOAT64 with count 1, offsets not
        ``0, 8, …`` in the listed order, big-endian, height ≠ 1, width 0 or above ``max_samples``, wrong strides,
        short data, unknown or missing axis, off-grid stamp, NaN/Inf.
    """
    try:
        header = _get(msg, "header")
        stamp_ns = stamp_to_ns(_get(header, "stamp"))
        height, width = int(_get(msg, "height")), int(_get(msg, "width"))
        point_step, row_step = int(_get(msg, "point_step")), int(_get(msg, "row_step"))
        big = bool(_get(msg, "is_bigendian"))
        fields = list(_get(msg, "fields"))
    except (KeyError, AttributeError, TypeError) as exc:
        raise BlockFormatError(f"block: not a PointCloud2-like message ({exc})") from None
    if big:
        raise BlockFormatError("block.is_bigendian: must be false (little-endian float64)")
    if height != 1:
        raise BlockFormatError(f"block.height: must be 1, got {height}")
    if width < 1:
        raise BlockFormatError(f"block.width: {width} samples (a block carries at least one)")
    if width > max_samples:   # before the data is touched: an oversized block costs nothing
        raise BlockFormatError(f"block.width: {width} samples > the {max_samples} a block may carry "
                               "(docs/topics.md)")
    if not fields:
        raise BlockFormatError("block.fields: empty")
    names: list[str] = []
    for i, f in enumerate(fields):
        name, off, dtype, count = str(_get(f, "name")), int(_get(f, "offset")), int(_get(f, "datatype")), \
            int(_get(f, "count"))
        if dtype != FLOAT64 or count != 1:
            raise BlockFormatError(f"block.fields[{name}]: must be FLOAT64 (8) with count 1, got datatype {dtype}, "
                                   f"count {count}")
        if off != 8 * i:
            raise BlockFormatError(f"block.fields[{name}].offset: {off}, expected {8 * i} (fields in offset order, "
                                   "no padding)")
        names.append(name)
    if len(set(names)) != len(names):
        raise BlockFormatError(f"block.fields: duplicate names {names}")
    if point_step != 8 * len(names):
        raise BlockFormatError(f"block.point_step: {point_step}, expected {8 * len(names)} for {len(names)} float64 "
                               "fields")
    if row_step != point_step * width:
        raise BlockFormatError(f"block.row_step: {row_step} != point_step·width = {point_step * width}")
    if axes is not None and sorted(names) != sorted(axes):
        raise BlockFormatError(f"block.fields: {names} do not name the axes {list(axes)} (missing "
                               f"{sorted(set(axes) - set(names))}, unknown {sorted(set(names) - set(axes))})")
    if period_ns is not None:
        check_stamp(stamp_ns, period_ns)
    try:
        data = _data_bytes(_get(msg, "data"))
    except (KeyError, AttributeError, TypeError) as exc:
        raise BlockFormatError(f"block: not a PointCloud2-like message ({exc})") from None
    nbytes = len(data) if not isinstance(data, np.ndarray) else data.nbytes
    if nbytes != row_step:
        raise BlockFormatError(f"block.data: {nbytes} bytes, expected row_step·height = {row_step}")
    table = np.frombuffer(data, dtype="<f8").reshape(width, len(names))
    cols = list(range(len(names))) if axes is None else [names.index(a) for a in axes]
    block = np.array(table[:, cols], dtype=np.float64)
    if finite and not np.all(np.isfinite(block)):
        raise BlockFormatError(f"block.data: {int(np.count_nonzero(~np.isfinite(block)))} NaN/Inf value(s)")
    return stamp_ns, block


def peek_block_samples(raw: bytes | bytearray | memoryview) -> int | None:
    """``height·width`` of a CDR-serialised block message, read from its first bytes only (no decoding): what a
    node checks against :data:`MAX_BLOCK_SAMPLES` before doing any work on a raw message; None if the bytes are
    too short to say."""
    import struct

    buf = memoryview(raw)
    if len(buf) < 4 + 8 + 4:
        return None
    endian = "<" if buf[1] == 1 else ">"   # encapsulation: CDR_LE = 00 01, CDR_BE = 00 00
    try:
        (n,) = struct.unpack_from(endian + "I", buf, 4 + 8)   # header.stamp (8 bytes), then frame_id's length
        off = 4 + 8 + 4 + n
        off = 4 + ((off - 4 + 3) & ~3)                        # uint32 alignment, relative to the payload
        height, width = struct.unpack_from(endian + "II", buf, off)
    except struct.error:
        return None
    return int(height) * int(width)


# ----------------------------------------------------------------------------------------------------------------
# CDR (de)serialisation without ROS, via the rosbags type store

@lru_cache(maxsize=1)
def typestore() -> Typestore:
    """The ``rosbags`` type store of the standard ROS 2 (Kilted) message types."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_KILTED)


def _build(ts: Typestore, type_name: str, value: Any) -> Any:
    """Nested dicts/lists → rosbags message objects of ``type_name``."""
    if not isinstance(value, Mapping):
        return value  # already a message object
    cls = ts.types[type_name]
    fields = ts.fielddefs[type_name][1]
    kwargs: dict[str, Any] = {}
    for fname, (kind, spec) in fields:
        if fname not in value:
            raise ValueError(f"{type_name}.{fname}: missing")
        v = value[fname]
        kwargs[fname] = _build_field(ts, kind, spec, v)
    return cls(**kwargs)


def _build_field(ts: Typestore, kind: Any, spec: Any, v: Any) -> Any:
    from rosbags.typesys.base import Nodetype

    if kind == Nodetype.NAME:
        return _build(ts, spec, v)
    if kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
        (sub_kind, sub_spec) = spec[0]
        if sub_kind == Nodetype.BASE and sub_spec[0] not in ("string", "bool"):
            dtype = {"int8": np.int8, "uint8": np.uint8, "char": np.uint8, "byte": np.uint8, "int16": np.int16,
                     "uint16": np.uint16, "int32": np.int32, "uint32": np.uint32, "int64": np.int64,
                     "uint64": np.uint64, "float32": np.float32, "float64": np.float64}[sub_spec[0]]
            if isinstance(v, (bytes, bytearray, memoryview)):
                return np.frombuffer(v, dtype=dtype)
            return np.asarray(v, dtype=dtype)
        return [_build_field(ts, sub_kind, sub_spec, x) for x in v]
    if kind == Nodetype.BASE and isinstance(v, (bytes, bytearray)) and len(v) == 1:
        return v[0]  # a ROS 'byte' given the way rclpy gives it (b'\x00')
    return v


def serialize_message(value: Any, type_name: str) -> bytes:
    """A standard message given as nested dicts (or rosbags objects) → CDR bytes (little-endian, with header)."""
    ts = typestore()
    if type_name not in ts.types:
        raise ValueError(f"{type_name}: unknown message type")
    return bytes(ts.serialize_cdr(_build(ts, type_name, value), type_name))


def deserialize_message(raw: bytes, type_name: str) -> Any:
    """CDR bytes → a rosbags message object (attributes as in the .msg; arrays of numbers as numpy arrays).

    Raises ``ValueError`` for an unknown type or bytes that do not decode.
    """
    ts = typestore()
    if type_name not in ts.types:
        raise ValueError(f"{type_name}: unknown message type")
    try:
        return ts.deserialize_cdr(bytes(raw) if not isinstance(raw, (bytes, memoryview)) else raw, type_name)
    except Exception as exc:  # rosbags raises assorted struct/index errors on corrupt data
        raise ValueError(f"{type_name}: cannot decode CDR message ({type(exc).__name__}: {exc})") from None


def serialize_block(block: ArrayLike, stamp_ns: int, axes: Sequence[str] = ("x", "y"),
                    frame_id: str = FRAME_ID) -> bytes:
    """Block [N, axes] → CDR-serialised ``sensor_msgs/msg/PointCloud2`` of the contract (bytes as in MCAP)."""
    return serialize_message(encode_block(block, stamp_ns, axes, frame_id), BLOCK_TYPE)


def deserialize_block(raw: bytes, axes: Sequence[str] | None = None, *, period_ns: int | None = None,
                      finite: bool = False, max_samples: int = MAX_BLOCK_SAMPLES) -> tuple[int, np.ndarray,
                                                                                          tuple[str, ...]]:
    """CDR bytes of a block message → ``(stamp_ns, block[N, axes], axes)``; ``ValueError`` if malformed.

    The same verdicts as :func:`decode_block` (same keywords): a reader and a node agree on what is a block.
    """
    msg = deserialize_message(raw, BLOCK_TYPE)
    names = block_axes(msg) if axes is None else tuple(axes)
    stamp_ns, block = decode_block(msg, names, period_ns=period_ns, finite=finite, max_samples=max_samples)
    return stamp_ns, block, names
