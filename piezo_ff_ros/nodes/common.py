"""What every node shares: the block message of the topic contract, QoS, stamps, diagnostics, the spin loop.

Block message (docs/topics.md): ``sensor_msgs/msg/PointCloud2`` used as a table of N samples, height 1, width N,
one FLOAT64 field per axis named after it, row-major little-endian ``[N, axes]`` data, ``header.stamp`` = time of
the first sample = ``t0 + k0·dt_ns`` with ``dt_ns = round(1e9/fs)`` so that sample indices are exact.  The codec
itself is :mod:`piezo_ff_ros.core.recording.blocks` (one codec for the nodes, the recorder and the readers).
"""
from __future__ import annotations

import faulthandler
import gc
import signal
import sys
import threading
import time
from typing import Any, Callable, Mapping, Sequence

import numpy as np

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2, PointField

from ..core.hardware.driver_core import ERROR, WARN
from ..core.recording import blocks
from ..core.recording.blocks import MAX_BLOCK_SAMPLES, BlockFormatError, sample_period_ns, stamp_to_ns

__all__ = ["BLOCK_QOS", "RECORD_QOS", "LATCHED_QOS", "CONFIG_QOS", "FRAME_ID", "dt_ns", "pack_block", "unpack_block",
           "stamp_to_ns", "ns_to_stamp", "k0_of", "spin_node", "freeze_startup_heap", "BlockFormatError", "log_lines",
           "writer_matches", "MAX_BLOCK_SAMPLES"]

FRAME_ID = blocks.FRAME_ID

#: blocks: reliable, keep-last 100, volatile — publishers and subscribers alike (a client that bursts more than 100
#: blocks at once loses the oldest: docs/topics.md says how to pace)
BLOCK_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.VOLATILE)
#: the recorder's subscriptions: same policies, deeper queue (a busy recorder must not lose blocks)
RECORD_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.VOLATILE)
#: ``experiment`` markers: late joiners (the recorder) still get the current segment
LATCHED_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)

#: the compensator's ``~/config`` (every configuration version): a recorder started late still gets them all
CONFIG_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL)


def dt_ns(sample_rate: float) -> int:
    """Sample period in integer nanoseconds (50 000 at 20 kHz); ``ValueError`` for a rate whose period is not a
    whole number of nanoseconds (:func:`piezo_ff_ros.core.recording.blocks.sample_period_ns`)."""
    return sample_period_ns(sample_rate)


def ns_to_stamp(ns: int, stamp: Any) -> None:
    """Write ``ns`` [ns] into a ``builtin_interfaces/Time`` (``sec``, ``nanosec``)."""
    t = blocks.ns_to_stamp(ns)
    stamp.sec, stamp.nanosec = t["sec"], t["nanosec"]


def k0_of(msg: Any, t0_ns: int, period_ns: int) -> int:
    """Index of the first sample of a block message."""
    return (stamp_to_ns(msg.header.stamp) - t0_ns) // period_ns


def pack_block(block: np.ndarray, axes: Sequence[str], stamp_ns: int, msg: PointCloud2 | None = None) -> PointCloud2:
    """``[N, axes]`` float array → PointCloud2 of the contract (:func:`~piezo_ff_ros.core.recording.blocks.
    encode_block`)."""
    d = blocks.encode_block(block, stamp_ns, axes)
    msg = PointCloud2() if msg is None else msg
    ns_to_stamp(stamp_ns, msg.header.stamp)
    msg.header.frame_id = d["header"]["frame_id"]
    msg.height, msg.width = d["height"], d["width"]
    msg.fields = [PointField(name=f["name"], offset=f["offset"], datatype=f["datatype"], count=f["count"])
                  for f in d["fields"]]
    msg.is_bigendian, msg.is_dense = d["is_bigendian"], d["is_dense"]
    msg.point_step, msg.row_step = d["point_step"], d["row_step"]
    msg.data = d["data"]
    return msg


def unpack_block(msg: PointCloud2, axes: Sequence[str] | None = None, *, period_ns: int | None = None,
                 finite: bool = False) -> np.ndarray:
    """PointCloud2 of the contract → ``[N, axes]`` float64 array (a copy); :class:`BlockFormatError` otherwise.

    The one codec (:func:`piezo_ff_ros.core.recording.blocks.decode_block`, same verdicts as the recorder and the
    readers): with ``axes`` (what a node that applies the block must pass) the columns are taken **by field name**,
    in the order of ``axes``; the fields must name exactly these axes.  ``period_ns``: a stamp off the sample grid
    is refused; ``finite``: a NaN/Inf value is refused.  The width is checked against
    :data:`~piezo_ff_ros.core.recording.blocks.MAX_BLOCK_SAMPLES` before the data is read.
    """
    return blocks.decode_block(msg, axes, period_ns=period_ns, finite=finite)[1]


#: how long a callback's fault may precede the context's shutdown and still count as part of the stop [s]
SHUTDOWN_GRACE_S = 0.5


def _context_ends(context: Any, within: float) -> bool:
    """True when ``context`` is shut down now or within ``within`` seconds (polled every 10 ms)."""
    deadline = time.monotonic() + within
    wake = threading.Event()
    while context.ok():
        if time.monotonic() >= deadline:
            return False
        wake.wait(0.01)
    return True


def freeze_startup_heap() -> int:
    """Leave everything allocated so far (imports, compiled kernels, the built node) out of garbage collection.

    A node's start-up heap (rclpy, numpy, scipy, numba) is large; Python's first full (generation-2) collection
    traverses all of it and, a few seconds into the first stream, stalled a node for 0.15 s alone and 0.3–0.8 s on a
    loaded 2-core host — past the driver's stale timeout and its write-ahead.  Collected once here, then frozen
    (:func:`gc.freeze`): later collections only walk what the stream allocates (milliseconds).  The frozen objects
    live as long as the process, as they would anyway.

    Returns
    -------
    int
        Objects frozen.
    """
    gc.collect()
    gc.freeze()
    return gc.get_freeze_count()   # O(objects), once


#: longest an idle executor waits before the spin loop looks at a stop request again [s]
STOP_POLL_S = 0.1


class StopRequest:
    """SIGINT/SIGTERM as a flag that the spin loop polls, instead of rclpy's own signal handling.

    rclpy's handler shuts the context down from its own thread and must then wake the executor; in full-suite runs
    that wake-up was lost now and then, and an idle node (a trajectory that had finished its run) sat in the
    executor's wait with no timeout, ignoring SIGINT until it was killed — its on-exit never ran.  Here the handler
    only records the signal; the spin loop waits at most :data:`STOP_POLL_S` at a time and, once asked, leaves the
    loop with the context still up, so ``on_exit`` (the driver's safe ramp) can still publish what it does.
    A second signal while stopping changes nothing: a ramp is never cut short by an impatient Ctrl-C.
    """

    SIGNALS = ("SIGINT", "SIGTERM")

    def __init__(self) -> None:
        self.signum: int | None = None
        self._previous: dict[int, Any] = {}

    def __call__(self, signum: int, frame: Any) -> None:
        if self.signum is None:
            self.signum = signum

    @property
    def requested(self) -> bool:
        """True once SIGINT or SIGTERM has arrived."""
        return self.signum is not None

    def install(self) -> bool:
        """Handle SIGINT/SIGTERM from now on; False (nothing changed) off the main thread, where Python cannot."""
        if threading.current_thread() is not threading.main_thread():
            return False
        for name in self.SIGNALS:
            signum = getattr(signal, name)
            self._previous[signum] = signal.signal(signum, self)
        return True

    def restore(self) -> None:
        """Put back the handlers :meth:`install` replaced."""
        while self._previous:
            signum, handler = self._previous.popitem()
            signal.signal(signum, handler)


def spin_node(node: Any, on_exit: Callable[[], None] | None = None, stop: StopRequest | None = None) -> int:
    """Spin until a stop: ``stop`` requested (SIGINT/SIGTERM through :class:`StopRequest`, as :func:`run_node`
    installs it) or the context shut down (ExternalShutdownException, KeyboardInterrupt with rclpy's own handler);
    then ``on_exit``; clean exit code 0.  The start-up heap is frozen first (:func:`freeze_startup_heap`): no full
    garbage collection of it stalls the stream."""
    code = 0
    name = node.get_name()   # read now: after a shutdown the node's handle is gone and get_name() raises
    executor = None
    try:
        # inside the try: a SIGINT during the (loaded-host: ~0.5 s) collection is a clean stop, on_exit included
        frozen = freeze_startup_heap()
        node.get_logger().info(f"start-up heap frozen: {frozen} objects out of garbage collection (no full "
                               "collection of them stalls the stream)")
        executor = SingleThreadedExecutor(context=node.context)
        executor.add_node(node)
        # never an unbounded wait: a stop request is seen within STOP_POLL_S even when nothing else happens
        while node.context.ok() and not (stop is not None and stop.requested):
            executor.spin_once(timeout_sec=STOP_POLL_S)
        print(f"{name}: stopping", file=sys.stderr, flush=True)
    except (KeyboardInterrupt, ExternalShutdownException):
        print(f"{name}: stopping", file=sys.stderr, flush=True)
    except Exception as exc:  # noqa: BLE001 - last resort: a clear one-line message, not a traceback
        if _context_ends(node.context, SHUTDOWN_GRACE_S):
            # SIGINT/SIGTERM shut the context down under a running callback (publish → InvalidHandle), or the
            # executor met a handle the shutdown had already destroyed just before the context said so: clean
            print(f"{name}: stopped during a callback ({type(exc).__name__}: {exc})", file=sys.stderr)
        else:
            print(f"{name}: fatal: {exc}", file=sys.stderr)
            code = 1
    finally:
        if executor is not None:
            executor.remove_node(node)
        if on_exit is not None:
            try:
                on_exit()
            except Exception as exc:  # noqa: BLE001
                print(f"{name}: error while finishing: {exc}", file=sys.stderr)
                code = 1
        if executor is not None:
            executor.shutdown(timeout_sec=0)
        node.destroy_node()
        rclpy.try_shutdown()
    return code


def run_node(name: str, make_node: Callable[[], Any], on_exit: Callable[[Any], None] | None = None,
             argv: Sequence[str] | None = None) -> int:
    """A node's ``main``: init rclpy with ``argv``, build the node (a bad config/parameter is one clear line and
    exit code 2, not a traceback), spin until SIGINT/SIGTERM, then ``on_exit(node)``.

    SIGINT/SIGTERM are handled here (:class:`StopRequest`), not by rclpy: the signal is polled by the spin loop,
    so no lost executor wake-up can leave the node deaf to it.  A signal while the node is being built stops it
    right after (on_exit included)."""
    args = sys.argv if argv is None else [sys.argv[0], *argv]
    if hasattr(signal, "SIGUSR1"):
        # `kill -USR1 <pid>` prints every thread's Python stack to stderr (the node's log): what a node that stopped
        # answering is waiting for
        faulthandler.register(signal.SIGUSR1, all_threads=True)
    stop = StopRequest()
    own_signals = stop.install()
    try:
        try:
            rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO if own_signals else None)
            node = make_node()
        except (KeyboardInterrupt, ExternalShutdownException):   # SIGINT/SIGTERM while starting: a clean stop
            print(f"{name}: stopped while starting", file=sys.stderr)
            rclpy.try_shutdown()
            return 0
        except Exception as exc:  # noqa: BLE001 - bad config/parameter: one clear line, no traceback
            print(f"{name}: error: {exc}", file=sys.stderr)
            rclpy.try_shutdown()
            return 2
        return spin_node(node, on_exit=(lambda: on_exit(node)) if on_exit is not None else None,
                         stop=stop if own_signals else None)
    finally:
        stop.restore()


def writer_matches(publishers: Mapping[str, Any]) -> dict[str, int]:
    """``{"matched.<topic>": readers this node's writer has matched}`` for its ``/diagnostics``.

    Discovery is asymmetric: a reader may match a writer (the recorder reports it connected) before the writer has
    matched the reader, and a volatile writer sends nothing to a reader it has not matched yet — the first blocks
    of a run would be missing from the recording.  A client that must not lose them waits until every writer has
    matched every reader of its topic (:meth:`piezo_ff_ros.ros.graph_session.GraphClient.wait_recorder_connected`).
    """
    return {f"matched.{t}": int(p.get_subscription_count()) for t, p in publishers.items() if p is not None}


def diag_values(d: Mapping[str, Any]) -> list[Any]:
    """dict → list of diagnostic_msgs/KeyValue."""
    from diagnostic_msgs.msg import KeyValue

    return [KeyValue(key=str(k), value=str(v)) for k, v in d.items()]


def log_lines(logger: Any, lines: Sequence[tuple[int, str]]) -> None:
    """Log a core's ``(level, text)`` lines (``OK``/``WARN``/``ERROR`` of
    :mod:`piezo_ff_ros.core.hardware.driver_core`: info, warning, error) on an rclpy logger."""
    for level, text in lines:  # one call site per severity (rclpy refuses a severity change per site)
        if level >= ERROR:
            logger.error(text)
        elif level >= WARN:
            logger.warning(text)
        else:
            logger.info(text)
