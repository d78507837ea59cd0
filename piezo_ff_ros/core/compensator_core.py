"""The compensator node without ROS: reference blocks in, voltage blocks out — and what to log, announce and set.

:class:`CompensatorCore` owns the :class:`~.hot_swap.HotSwapCascade` (the cascade, its bumpless swaps and the
re-synchronisation on the applied voltage), the tracking front (:class:`~.tracking.front.TrackingFront`), the
held-point pacer (:class:`~.hold_pacer.HoldPacer`), the input-stream bookkeeping, the workspace clamp, the counters
and the ``/diagnostics`` status; its :class:`~.parameter_book.ParameterBook` holds the stage parameters and runs the
parameter transactions.  The compensator node only declares and types the ROS parameters, converts messages, and publishes,
logs and sets what each call returns in a :class:`CompensatorOutput`:

- ``on_reference(stamp, block, now)`` — a reference block from the topic: NaN/Inf, an empty block, a stamp off the
  sample grid and a sample outside ``reference_limit`` (when it is empty: beyond :data:`HARD_REFERENCE_FACTOR` ×
  the stage's reach) refused (counted, one ERROR line a second at most,
  ``/diagnostics`` at ERROR while it lasts); a jump of more than 1 s in the stamps is a new stream or a stray stamp
  (``input_jumps``), never lost samples; after a pause of
  ``max(hold_timeout, 0.5 s)`` a jump in the stamps starts a new stream, otherwise a jump forward is a gap (lost
  blocks, counted with their samples) and a jump back a late block; then the workspace clamp (counted, a WARN at
  most once a second), the tracking front and the cascade (``bypass``: the block is forwarded unchanged);
- ``process(block, None, now)`` — a block of the held point: its stamp continues the stream (or starts it on the
  wall clock's sample grid);
- ``on_applied(stamp, u, now, foreign)`` — the driver's applied voltage, for the re-synchronisation of the inverse
  models: only from the paired driver (the node says who else sent it), finite, on the grid, within
  ``±limits.voltage`` and not beyond the stream produced — anything else refused and counted (``applied_rejected``);
- ``propose(params)`` then ``commit(params)`` — a parameter change: validated as a whole
  (:meth:`ParameterBook.propose`, the on-set check; a rejection's reason starts with the field's name) and applied
  after (node settings, the tracking front, a new configuration — built in the background when it needs an H∞
  synthesis —, or no version at all when the values are those that run);
- ``poll()`` — a finished build made active, a failed one reported with the parameters reverted to the running
  configuration (without a new version);
- ``status()`` and ``diagnostics()`` — the ``/diagnostics`` key/values, level and message.

Not thread-safe: the node serialises the calls (one lock, held while it publishes what a data-path call returned,
so that the stamps leave in order).
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Literal, Mapping, Sequence

import numpy as np

from .config import PiezoConfig
from .hold_pacer import HOLD_BLOCK_SIZE, HoldPacer
from .hot_swap import CascadeFactory, HotSwapCascade
from .param_map import needs_synthesis
from .parameter_book import ParameterBook, Verdict, check_box_parameter, parse_config_yaml, same_value
from .recording.blocks import BlockFormatError, check_stamp, sample_period_ns
from .status import ERROR, OK, WARN
from .tracking.front import TrackingFront
from .tracking.linear import controller_matrices
from .trajectories.workspace import reachable_range

__all__ = ["CompensatorCore", "CompensatorSettings", "CompensatorOutput", "ParameterBook", "SETTING_NAMES", "Verdict",
           "VoltageBlock", "build_notice", "check_box_parameter", "parse_config_yaml", "same_value", "OK", "WARN",
           "ERROR"]

#: the node parameters that are not stage parameters and change the running core (:class:`CompensatorSettings`)
SETTING_NAMES = ("crossfade", "block_size", "hold_timeout", "bypass", "resync", "workspace", "reference_limit")

#: the ``input_*`` counters of ``/diagnostics`` (without the prefix), in their order
_INPUT_KEYS = ("gaps", "gap_samples", "late_blocks", "jumps", "workspace_clamped_samples")

#: the status keys whose non-zero value makes ``/diagnostics`` WARN
_WARN_KEYS = ("failed_builds", "rejected_blocks", "applied_rejected", "input_gaps", "input_late_blocks",
              "input_jumps", "input_workspace_clamped_samples")

#: a jump in the reference stamps of more than this [s] is no gap (no lost blocks are that long): a stray stamp or
#: a new stream, counted in ``input_jumps`` and never as lost samples
_MAX_GAP_S = 1.0

#: a reference beyond this many times the stage's reach (:func:`~.trajectories.workspace.reachable_range` at
#: margin 1: the static gain times ``±limits.voltage``) is refused even with ``reference_limit`` empty.  The
#: hysteresis inverse handles any finite reference with bounded work, but the linear stages (C(s), the creep
#: inverse) have no saturation: their states grow with the reference, and far enough out (~1e300 m) they overflow
#: and would stay non-finite.  1e12 × tens of µm is ~1e7 m: no real reference comes near it.
HARD_REFERENCE_FACTOR = 1e12








def build_notice(cfg: PiezoConfig) -> str:
    """The log line before the first cascade is built (it says when an H∞ synthesis makes that slow).

    Parameters
    ----------
    cfg : PiezoConfig
        The configuration about to be built.

    Returns
    -------
    str
        ``building the compensator cascade`` (``… (H∞ synthesis)`` when C(s) is synthesised).
    """
    return "building the compensator cascade" + (" (H∞ synthesis)" if cfg.cascade.vibration
                                                 and cfg.vibration.controller is None else "")




@dataclass(frozen=True)
class CompensatorSettings:
    """The node parameters of the running compensator that are not stage parameters (:data:`SETTING_NAMES`).

    Attributes
    ----------
    crossfade : float
        Output crossfade at a configuration swap [s].
    block_size : int
        Samples per block played from a held point.
    hold_timeout : float
        The held point plays once no reference block came for this long [s]; a pause of ``max(hold_timeout,
        0.5 s)`` between reference blocks starts a new stream.
    bypass : bool
        Reference blocks are voltages [V], forwarded unchanged (the cascade is not run).
    resync : bool
        Follow the applied voltage and re-synchronise the hysteresis/creep states on it.
    workspace : tuple of float
        ``[min_x, max_x, min_y, …]`` [m] the reference is clamped to; empty = none.
    reference_limit : tuple of float
        ``[min_x, max_x, min_y, …]`` [m]: a reference block (or ``reference_point``) with a sample outside is
        refused whole (the node's default: the stage's reachable range with a margin,
        :func:`~.trajectories.workspace.reachable_range`); empty = only the hard bound, :data:`HARD_REFERENCE_FACTOR`
        × the stage's reach.  In ``bypass`` the reference is in volts and ``±limits.voltage`` bounds it instead.
    """

    crossfade: float = 0.01
    block_size: int = HOLD_BLOCK_SIZE
    hold_timeout: float = 0.2
    bypass: bool = False
    resync: bool = True
    workspace: tuple[float, ...] = ()
    reference_limit: tuple[float, ...] = ()

    def validate(self, n_axes: int) -> "CompensatorSettings":
        """Check the workspace boxes against the number of axes (:func:`check_box_parameter`); returns self.

        Parameters
        ----------
        n_axes : int
            Number of axes of the configuration.

        Returns
        -------
        CompensatorSettings
            self.
        """
        check_box_parameter(self.workspace, n_axes)
        check_box_parameter(self.reference_limit, n_axes, "reference_limit")
        return self

    def with_value(self, name: str, value: Any) -> "CompensatorSettings":
        """A copy with the setting ``name`` (one of :data:`SETTING_NAMES`) set to ``value``, converted to its type.

        Parameters
        ----------
        name : str
            Setting name.
        value : Any
            New value as the node parameter holds it.

        Returns
        -------
        CompensatorSettings
            The new settings.
        """
        conv: dict[str, Callable[[Any], Any]] = {"crossfade": float, "block_size": int, "hold_timeout": float,
                                                 "bypass": bool, "resync": bool,
                                                 "workspace": lambda v: tuple(float(x) for x in v),
                                                 "reference_limit": lambda v: tuple(float(x) for x in v)}
        return replace(self, **{name: conv[name](value)})

    def crossfade_samples(self, sample_rate: float) -> int:
        """The crossfade as a whole number of samples at ``sample_rate`` [Hz].

        Parameters
        ----------
        sample_rate : float
            Samples per second [Hz].

        Returns
        -------
        int
            ``round(crossfade · sample_rate)``.
        """
        return int(round(self.crossfade * sample_rate))


@dataclass(frozen=True, eq=False)
class VoltageBlock:
    """One voltage block to publish.

    Attributes
    ----------
    stamp : int
        Stamp of the first sample [ns] (the reference block's).
    u : numpy.ndarray
        Voltages ``[N, axes]`` [V].
    config : dict or None
        A configuration that takes effect with this block, to announce before it on ``~/config``: ``{"version",
        "stamp_ns", "config_yaml"}`` (the node adds ``"parameters"``); None when the version is unchanged.
    """

    stamp: int
    u: np.ndarray
    config: dict[str, Any] | None = None


@dataclass
class CompensatorOutput:
    """What a call produced, for the node to publish, log and set.

    Attributes
    ----------
    voltage : list of VoltageBlock
        Voltage blocks to publish, in order.
    log : list of (int, str)
        Log lines ``(level, text)``, level :data:`OK` (info), :data:`WARN` or :data:`ERROR`.
    readback : dict
        After a ``config_yaml`` change: the parameters to set on the node so that it reads back what now runs (the
        stage parameters — those whose value differs — and ``config_yaml`` cleared), without a validation round.
    revert : dict
        After a failed build: the stage parameters to set back to the running configuration's values (only those
        that differ), without a validation round.
    diagnostics : bool
        Publish ``/diagnostics`` now.
    hold_timer : {"start", "retime"} or None
        The held point's timer: start it (a point is held) or re-create it for a new block period.
    """

    voltage: list[VoltageBlock] = field(default_factory=list)
    log: list[tuple[int, str]] = field(default_factory=list)
    readback: dict[str, Any] = field(default_factory=dict)
    revert: dict[str, Any] = field(default_factory=dict)
    diagnostics: bool = False
    hold_timer: Literal["start", "retime"] | None = None








class _Throttle:
    """True at most once per ``period`` seconds."""

    def __init__(self, period: float) -> None:
        self.period = period
        self._last = -math.inf

    def due(self, now: float) -> bool:
        if now - self._last > self.period:
            self._last = now
            return True
        return False


class CompensatorCore:
    """The compensator's logic (see the module docstring).

    Parameters
    ----------
    book : ParameterBook
        The declared parameters (:meth:`ParameterBook.end_declarations` called).
    cfg : PiezoConfig
        The configuration they give (built here, synchronously: an H∞ synthesis takes seconds).
    settings : CompensatorSettings
        The node settings.
    factory : callable, optional
        Builds a cascade (:class:`~.hot_swap.HotSwapCascade`'s ``factory``; tests inject failing ones).
    wall_ns : callable, optional
        Wall clock [ns] where a held point starts a stream (default ``time.time_ns``).
    applied_feedback : callable, optional
        Whether a driver reports the voltage it applied (a ``voltage_applied`` publisher exists): the blocks are
        kept in flight for the re-synchronisation only then (default: never).

    Attributes
    ----------
    hs : HotSwapCascade
        The running cascade.
    front : TrackingFront
        The tracking stages in front of it.
    pacer : HoldPacer
        When the held point plays.
    cfg : PiezoConfig
        The active configuration.
    axes : tuple of str
        The axes (the block fields).
    period_ns : int
        Sample period [ns].
    blocks : int
        Blocks processed.
    rejected_blocks : int
        Reference blocks rejected (malformed, NaN/Inf).
    applied_rejected : int
        ``voltage_applied`` blocks rejected.
    input : dict
        ``gaps``, ``gap_samples``, ``late_blocks``, ``workspace_clamped_samples``.
    last_error : str
        The last error (a rejected block, a failed build).
    """

    def __init__(self, book: ParameterBook, cfg: PiezoConfig, settings: CompensatorSettings, *,
                 factory: CascadeFactory | None = None, wall_ns: Callable[[], int] = time.time_ns,
                 applied_feedback: Callable[[], bool] = lambda: False) -> None:
        self.book = book
        self.settings = settings.validate(len(book.base.axes))
        self.cfg = cfg
        self.axes = cfg.axes
        self.period_ns = sample_period_ns(cfg.sample_rate)
        self.wall_ns = wall_ns
        self.applied_feedback = applied_feedback
        self.hs = HotSwapCascade(cfg, crossfade_samples=settings.crossfade_samples(cfg.sample_rate), factory=factory)
        self.front = TrackingFront(cfg, controller_matrices(self.hs.active), book.front_values)
        self.pacer = HoldPacer(cfg.sample_rate, settings.block_size, settings.hold_timeout)
        self.blocks = 0
        self.rejected_blocks = 0
        self.applied_rejected = 0
        self.input = dict.fromkeys(_INPUT_KEYS, 0)
        self.last_error = ""
        self._expected_k: int | None = None       # first sample of the next reference block, if the stream goes on
        self._next_stamp: int | None = None       # stamp of the next sample produced (a held block continues there)
        self._last_block_wall = -math.inf         # when the last reference block came [s, monotonic]
        self._announced_version: int | None = None
        self._seen_failed = 0
        self._ws_warn = _Throttle(1.0)
        self._resync_warn = _Throttle(1.0)
        self._jump_warn = _Throttle(1.0)
        self._reject_log = {"reference": _Throttle(1.0), "voltage_applied": _Throttle(1.0)}
        self._refused_now = {"reference": 0, "voltage_applied": 0}   # since the last diagnostics() call
        self._last_refusal = {"reference": "", "voltage_applied": ""}
        self._hard_bound: tuple[PiezoConfig, np.ndarray] | None = None

    # -- data path -------------------------------------------------------------------------------------------------
    def on_reference(self, stamp: int, block: np.ndarray, now: float) -> CompensatorOutput:
        """A reference block from the topic.

        Parameters
        ----------
        stamp : int
            Stamp of its first sample [ns].
        block : numpy.ndarray
            ``[N, axes]`` [m] (``bypass``: [V]).
        now : float
            Monotonic clock [s]: a block after a pause of ``max(hold_timeout, 0.5 s)`` starts a new stream (a jump
            in the stamps is then no gap); the held point waits for the stream to go quiet again.

        Returns
        -------
        CompensatorOutput
            The voltage block (and a configuration announcement), or the rejection of a block with NaN/Inf.
        """
        if block.ndim != 2 or block.shape[0] < 1 or block.shape[1] != len(self.axes):
            return self.reject("reference", f"block: shape {block.shape}, expected [N ≥ 1, {len(self.axes)}]")
        if not np.all(np.isfinite(block)):
            return self.reject("reference", "NaN/Inf in the reference")
        try:
            check_stamp(stamp, self.period_ns)
        except BlockFormatError as exc:
            return self.reject("reference", str(exc))
        outside = self._outside_limit(block)
        if outside:
            return self.reject("reference", outside)
        restart = now - self._last_block_wall > max(self.settings.hold_timeout, 0.5)
        self._last_block_wall = now
        self.pacer.note_block(now)
        return self.process(block, stamp, now, from_topic=True, restart=restart)

    def reject(self, topic: Literal["reference", "voltage_applied"], reason: str) -> CompensatorOutput:
        """A block of ``topic`` that cannot be used (malformed, NaN/Inf): counted and logged; a reference block's
        error is kept as the last error too.

        Parameters
        ----------
        topic : {"reference", "voltage_applied"}
            Where it came from (``rejected_blocks`` or ``applied_rejected`` counts it).
        reason : str
            What is wrong with it.

        Returns
        -------
        CompensatorOutput
            The error line (at most one a second per topic, with the count so far; every block is counted and
            ``/diagnostics`` is at ERROR until the next report).
        """
        text = f"{topic} block rejected: {reason}"
        if topic == "reference":
            self.rejected_blocks += 1
            self.last_error = text
            total = self.rejected_blocks
        else:
            self.applied_rejected += 1
            total = self.applied_rejected
        self._refused_now[topic] += 1
        self._last_refusal[topic] = text
        # one line a second at most: a flood of bad blocks must not flood the log (every one is counted)
        if self._reject_log[topic].due(time.monotonic()):
            return CompensatorOutput(log=[(ERROR, text + (f" ({total} so far)" if total > 1 else ""))])
        return CompensatorOutput()

    def _outside_limit(self, block: np.ndarray) -> str:
        """Why ``block`` lies outside the reference limit (``reference_limit`` [m]; ``bypass``: ±limits.voltage
        [V]); empty when it does not."""
        if self.settings.bypass:
            v = float(self.cfg.limits.voltage)
            lo, hi, name, unit = np.full(len(self.axes), -v), np.full(len(self.axes), v), "limits.voltage", "V"
        elif self.settings.reference_limit:
            lim = self.settings.reference_limit
            lo, hi, name, unit = np.asarray(lim[0::2]), np.asarray(lim[1::2]), "reference_limit", "m"
        else:
            return self._beyond_hard_bound(block)
        bad = np.any((block < lo) | (block > hi), axis=1)
        n = int(np.count_nonzero(bad))
        if not n:
            return ""
        worst = block[int(np.argmax(bad))]
        return (f"{name}: {n} sample(s) outside {[float(x) for pair in zip(lo, hi) for x in pair]} [{unit}] "
                f"(e.g. {[float(f'{x:.6g}') for x in worst]}); adjust {name} if the stage really goes there")

    def _beyond_hard_bound(self, block: np.ndarray) -> str:
        """Why ``block`` lies beyond ``±HARD_REFERENCE_FACTOR ×`` the stage's reach (checked when
        ``reference_limit`` is empty); empty when it does not."""
        if self._hard_bound is None or self._hard_bound[0] is not self.cfg:
            reach = np.abs(np.asarray(reachable_range(self.cfg, margin=1.0), float)).reshape(-1, 2).max(axis=1)
            self._hard_bound = (self.cfg, HARD_REFERENCE_FACTOR * reach)
        bound = self._hard_bound[1]
        bad = np.any(np.abs(block) > bound, axis=1)
        n = int(np.count_nonzero(bad))
        if not n:
            return ""
        worst = block[int(np.argmax(bad))]
        return (f"hard reference bound: {n} sample(s) beyond ±{[float(f'{b:.6g}') for b in bound]} [m] "
                f"(e.g. {[float(f'{x:.6g}') for x in worst]}; {HARD_REFERENCE_FACTOR:g} × the stage's reach at "
                f"±limits.voltage), refused even with reference_limit empty")

    def process(self, block: np.ndarray, stamp: int | None, now: float, *, from_topic: bool = False,
                restart: bool = False) -> CompensatorOutput:
        """One block through the input bookkeeping, the workspace clamp, the front and the cascade.

        Parameters
        ----------
        block : numpy.ndarray
            ``[N, axes]`` reference [m] (``bypass``: voltages [V], forwarded unchanged).
        stamp : int or None
            Stamp of its first sample [ns]; None (a held point): the stamp after the last block produced, or the
            current wall-clock sample when nothing was produced yet.
        now : float
            Monotonic clock [s] (the workspace WARN comes at most once a second).
        from_topic : bool
            A block of the reference stream: checked against the expected sample (gaps, late blocks).
        restart : bool
            The stream restarts here (after a pause): a jump in the stamps is not counted.

        Returns
        -------
        CompensatorOutput
            The voltage block, with the configuration to announce before it when a new version produced it first;
            WARN lines for a gap or a clamped reference.
        """
        em = CompensatorOutput()
        if stamp is None:   # held point: continue the sample stream (or start it on the wall clock)
            stamp = self._next_stamp if self._next_stamp is not None else \
                self.wall_ns() // self.period_ns * self.period_ns
        n = block.shape[0]
        k0 = stamp // self.period_ns
        if from_topic:
            self._book_input(k0, n, stamp, restart, em)
        if self.settings.bypass:
            u = block
        else:
            # in flight only while a driver reports what it applied (else nothing would ever confirm them)
            track = self.settings.resync and self.applied_feedback()
            x = self._clamp_to_workspace(block, now, em)
            u = self.hs.process(self.front.process(x) if self.front.active else x, k0=k0 if track else None)
        self.blocks += 1
        self._next_stamp = stamp + n * self.period_ns
        config = None
        if self.hs.version != self._announced_version:
            self._announced_version = self.hs.version
            config = {"version": self.hs.version, "stamp_ns": int(stamp), "config_yaml": self.hs.cfg.to_yaml()}
        em.voltage.append(VoltageBlock(stamp, u, config))
        return em

    def _book_input(self, k0: int, n: int, stamp: int, restart: bool, em: CompensatorOutput) -> None:
        expected = self._expected_k
        if not restart and expected is not None and abs(k0 - expected) > _MAX_GAP_S * self.cfg.sample_rate:
            # a stray stamp or a new stream, not lost blocks: counted as a jump, never as gap samples
            self.input["jumps"] += 1
            if self._jump_warn.due(time.monotonic()):
                em.log.append((WARN, f"reference stamps jumped by {k0 - expected} samples at stamp {stamp} (more "
                                     f"than {_MAX_GAP_S:g} s): a new stream or a stray stamp, not counted as lost"))
        elif not restart and expected is not None and k0 != expected:
            if k0 > expected:
                self.input["gaps"] += 1
                self.input["gap_samples"] += int(k0 - expected)
                em.log.append((WARN, f"reference gap: {k0 - expected} samples missing before stamp {stamp}"))
            else:
                self.input["late_blocks"] += 1
        self._expected_k = k0 + n

    def _clamp_to_workspace(self, block: np.ndarray, now: float, em: CompensatorOutput) -> np.ndarray:
        ws = self.settings.workspace
        if not ws:
            return block
        lo, hi = np.asarray(ws[0::2]), np.asarray(ws[1::2])
        out: np.ndarray = np.clip(block, lo, hi)
        n = int(np.count_nonzero(np.any(out != block, axis=1)))
        if n:
            self.input["workspace_clamped_samples"] += n
            if self._ws_warn.due(now):
                em.log.append((WARN, f"reference outside the workspace {list(ws)} [m]: {n} samples clamped "
                                     f"(total {self.input['workspace_clamped_samples']})"))
        return out

    @property
    def wants_applied(self) -> bool:
        """Whether ``voltage_applied`` blocks are used (``resync``): otherwise they are ignored unread."""
        return self.settings.resync

    def on_applied(self, stamp: int, u: np.ndarray, now: float, foreign: str = "") -> CompensatorOutput:
        """The voltage the driver applied (same stamps as the voltage blocks): re-synchronise where it differs.

        Only what the paired driver could have applied is used: a block from another sender (``foreign``: who sent
        it, as the node found out), with NaN/Inf, off the sample grid or beyond ``±limits.voltage`` is refused and
        counted (``applied_rejected``), the states stay as they are.

        Parameters
        ----------
        stamp : int
            Stamp of its first sample [ns].
        u : numpy.ndarray
            ``[N, axes]`` [V].
        now : float
            Monotonic clock [s] (the re-synchronisation WARN comes at most once a second).
        foreign : str
            Non-empty: the block does not come from the paired driver (the text says from whom).

        Returns
        -------
        CompensatorOutput
            A WARN line when the states were re-synchronised, an ERROR line (at most once a second) for a refusal.
        """
        if foreign:
            return self.reject("voltage_applied", foreign)
        if u.ndim != 2 or u.shape[0] < 1 or u.shape[1] != len(self.axes):
            return self.reject("voltage_applied", f"block: shape {u.shape}, expected [N ≥ 1, {len(self.axes)}]")
        if not np.all(np.isfinite(u)):
            return self.reject("voltage_applied", "NaN/Inf in the applied voltage")
        try:
            check_stamp(stamp, self.period_ns)
        except BlockFormatError as exc:
            return self.reject("voltage_applied", str(exc))
        horizon = self._next_stamp + int(_MAX_GAP_S * self.cfg.sample_rate) * self.period_ns \
            if self._next_stamp is not None else None
        if horizon is not None and stamp > horizon:
            # no driver applies samples more than 1 s beyond what it was sent (a hold before them would be that
            # long: a stamp 1e12 samples ahead asked for terabytes)
            return self.reject("voltage_applied", f"block.header.stamp: {stamp} ns is more than {_MAX_GAP_S:g} s "
                                                  f"ahead of the voltage produced (next {self._next_stamp} ns)")
        v = float(self.cfg.limits.voltage)
        if np.any(np.abs(u) > v * (1 + 1e-9)):
            return self.reject("voltage_applied", f"limits.voltage: {float(np.max(np.abs(u))):.6g} V beyond ±{v:g} V "
                                                  "(no driver applies that)")
        em = CompensatorOutput()
        if self.hs.applied(stamp // self.period_ns, u) == "resync" and self._resync_warn.due(now):
            em.log.append((WARN, "applied voltage differs from the command: hysteresis/creep states "
                                 f"re-synchronised ({self.hs.resyncs} so far)"))
        return em

    def set_point(self, point: Sequence[float]) -> CompensatorOutput:
        """Hold ``point`` (one value per axis, [m]): played as blocks while no reference block comes.

        Parameters
        ----------
        point : sequence of float
            The set-point.

        Returns
        -------
        CompensatorOutput
            Start the hold timer, or an error line (NaN/Inf: refused, the previous point stays).
        """
        if not np.all(np.isfinite(point)):
            return CompensatorOutput(log=[(ERROR, "reference_point rejected: NaN/Inf")])
        outside = self._outside_limit(np.asarray(point, float)[None, :])
        if outside:
            self.rejected_blocks += 1
            self.last_error = f"reference_point rejected: {outside}"
            self._refused_now["reference"] += 1
            self._last_refusal["reference"] = self.last_error
            return CompensatorOutput(log=[(ERROR, self.last_error + "; the previous point stays")])
        self.pacer.set_point(point)
        return CompensatorOutput(hold_timer="start")

    def reset(self) -> str:
        """All compensator states back to rest (a finished pending configuration is applied first), the held point
        forgotten, the next reference block starts a new stream.

        Returns
        -------
        str
            What was done, for the service's answer.
        """
        self.hs.reset()
        self.front.reset()
        self.pacer.clear()
        self._next_stamp = None
        self._expected_k = None
        return f"compensator states reset (config v{self.hs.version})"

    # -- parameters ------------------------------------------------------------------------------------------------
    def _front_for(self, values: Mapping[str, Any]) -> TrackingFront:
        return TrackingFront(self.hs.cfg, controller_matrices(self.hs.active), values)

    def propose(self, params: Sequence[tuple[str, Any]]) -> Verdict:
        """Validate a parameter change (:meth:`ParameterBook.propose`, the tracking front built for the running
        cascade).

        Parameters
        ----------
        params : sequence of (str, Any)
            ``(name, value)`` of the parameters being set, together.

        Returns
        -------
        Verdict
            Accepted (kept for :meth:`commit`) or refused with the reason.
        """
        return self.book.propose(params, self._front_for)

    def commit(self, params: Sequence[tuple[str, Any]]) -> CompensatorOutput:
        """Apply an accepted change (the node's post-set): node settings, the new tracking front, the new
        configuration.

        Setting stage parameters to the configuration that runs (or is being built) creates no version; a change
        that needs an H∞ synthesis (or a design not cached) is built in the background while the old cascade runs,
        any other synchronously; either takes over at a block boundary.

        Parameters
        ----------
        params : sequence of (str, Any)
            ``(name, value)`` of the parameters set.

        Returns
        -------
        CompensatorOutput
            Info lines, the read-back after ``config_yaml``, ``/diagnostics`` when a version was requested, the hold
            timer re-timed for a new block size.
        """
        em = CompensatorOutput()
        for name, value in params:
            if name not in SETTING_NAMES:
                continue
            self.settings = self.settings.with_value(name, value)
            if name == "crossfade":
                self.hs.crossfade_samples = self.settings.crossfade_samples(self.cfg.sample_rate)
            elif name == "block_size":
                self.pacer.set_block_size(self.settings.block_size)
                em.hold_timer = "retime"
            elif name == "hold_timeout":
                self.pacer.hold_timeout = self.settings.hold_timeout
        front = self.book.take_front()
        if front is not None:
            self.book.front_values, self.front = front
            f = self.front
            em.log.append((OK, f"tracking front: preview {'on' if f.preview else 'off'} (reference needed "
                               f"{f.preview_s:g} s ahead), learning {f.learning_file or 'off'}"))
        cand = self.book.take_candidate()
        if cand is None:
            return em
        updates, cfg, from_yaml = cand
        self.book.values.update(updates)
        if from_yaml:   # the stage parameters read back what now runs; config_yaml is a one-shot input
            em.readback = {**updates, "config_yaml": ""}
        names = ", ".join(sorted(updates))
        if cfg == (self.hs.pending_cfg or self.hs.cfg):
            em.log.append((OK, f"parameters set to the values that run ({names}): no new configuration"))
            return em
        bg = any(needs_synthesis(n) for n in updates) or self.hs.needs_background(cfg)
        v = self.hs.request(cfg, background=bg)
        em.log.append((OK, f"configuration v{v} requested ({names})" + ("; building in the background" if bg else "")))
        em.diagnostics = True
        return em

    def poll(self) -> CompensatorOutput:
        """Make a finished build active even when no block flows; report swaps and failed builds (including those
        the data path found first: :meth:`HotSwapCascade.process` polls too).

        A failed build is logged at ERROR, kept as the last error, and the stage parameters are reverted to the
        running configuration (no new version).  A new active configuration rebuilds an active tracking front for
        it (the preview inverts the running cascade), keeping the learned correction's position.

        Returns
        -------
        CompensatorOutput
            Log lines, the parameters to revert, ``/diagnostics`` when something changed.
        """
        em = CompensatorOutput()
        hs = self.hs
        hs.poll()
        if hs.failed_builds != self._seen_failed:
            self._seen_failed = hs.failed_builds
            self.last_error = hs.last_error
            em.log.append((ERROR, hs.last_error + f"; parameters reverted to the running configuration v{hs.version}"))
            em.revert = self.book.revert_to(hs.cfg)
            em.diagnostics = True
        if self.cfg is not hs.cfg:
            self.cfg = hs.cfg
            if self.front.active:   # the preview inverts the running cascade: rebuild it for the new one
                old = self.front
                self.front = TrackingFront(hs.cfg, controller_matrices(hs.active), self.book.front_values)
                self.front.continue_from(old)
            em.log.append((OK, f"configuration v{hs.version} active"))
            em.diagnostics = True
        return em

    # -- diagnostics -----------------------------------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        """The ``/diagnostics`` key/values (a contract: docs/nodes.md).

        Returns
        -------
        dict
            :meth:`HotSwapCascade.status`, ``bypass``, ``blocks``, ``rejected_blocks``, ``input_*``,
            ``applied_rejected``, ``stages``, ``order``, ``resync_active``, ``preview_s``, ``learning_file``;
            ``last_error``, ``hysteresis_fallbacks`` and ``hinf`` (JSON of the H∞ design) where they apply.
        """
        hs = self.hs
        st = {**hs.status(), "bypass": self.settings.bypass, "blocks": self.blocks,
              "rejected_blocks": self.rejected_blocks, **{f"input_{k}": v for k, v in self.input.items()},
              "applied_rejected": self.applied_rejected,
              "stages": ",".join(k for k in ("vibration", "creep", "hysteresis") if getattr(hs.cfg.cascade, k)),
              "order": hs.cfg.cascade.order,
              # re-synchronisation needs the paper order (commuted: the voltage leaves C(s), not the hysteresis⁻¹)
              "resync_active": bool(self.settings.resync and hs.active.can_follow),
              "preview_s": self.front.preview_s, "learning_file": self.front.learning_file,
              "reference_limit": list(self.settings.reference_limit)}
        if self.last_error:
            st["last_error"] = self.last_error
        h = hs.active.hysteresis
        if h is not None:
            st["hysteresis_fallbacks"] = h.fallbacks
        design = getattr(hs.active, "design", None)
        if design is not None and hasattr(design, "as_dict"):
            d = design.as_dict()  # γ and orders of the H∞ design in use (recorded with /diagnostics)
            st["hinf"] = json.dumps({k: d.get(k) for k in ("gamma", "order_full", "order_reduced",
                                                             "gamma_reduced_achieved", "synthesis_s")})
        return st

    def diagnostics(self) -> tuple[int, str, dict[str, Any]]:
        """Level, message and key/values of the ``/diagnostics`` status.

        Returns
        -------
        (int, str, dict)
            :data:`ERROR` while blocks are being refused (since the previous call: the message says what and
            why), :data:`WARN` when a build failed or input was rejected, lost, late, jumped or clamped, else
            :data:`OK`; the message ``config v<n>`` (then the last error after a failed build, and the counts that
            warn); the :meth:`status`.
        """
        st = self.status()
        warn = [k for k in _WARN_KEYS if st.get(k)]
        msg = f"config v{st['config_version']}"
        refusing = [f"{n} {topic} block(s) refused now ({self._last_refusal[topic]})"
                    for topic, n in self._refused_now.items() if n]
        self._refused_now = dict.fromkeys(self._refused_now, 0)
        if refusing:
            msg += "; " + "; ".join(refusing)
        if st["failed_builds"] and self.last_error:
            msg += f"; {self.last_error}"
        if warn:
            msg += "; " + ", ".join(f"{k} {st[k]}" for k in warn)
        return (ERROR if refusing else WARN if warn else OK), msg, st
