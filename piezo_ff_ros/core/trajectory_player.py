"""Playing a trajectory as stamped reference blocks: the trajectory node's logic, without ROS (pure).

A :class:`TrajectoryPlayer` plays a :class:`~piezo_ff_ros.core.trajectories.Trajectory` block by block on the
stream's sample grid (sample ``k`` stamped ``t0_ns + k·period_ns``; the stream index never goes back), in one of two
modes:

- ``realtime``: paced by the clock (sleep until each block is due); the first sample is stamped with the wall clock
  at the start, so that the stamps measure latency;
- ``lockstep``: as fast as the graph answers, deterministic and lossless.  At most ``window`` blocks are in flight;
  the next block is sent when the ``displacement`` of an earlier one came back (:meth:`TrajectoryPlayer.on_ack`).
  A block not answered within ``ack_timeout`` is given up (its node died, or the driver dropped it), counted as
  ``unanswered_blocks`` with a WARN, so that a restarted node rejoins the run; an answer for a later stamp gives up
  the earlier blocks at once (the driver's stream never goes back).  No answer at all for ``lockstep_timeout``
  while blocks are in flight fails the run.

The segments of a trajectory made of named segments (one with ``segments(fs)``) are announced as ``experiment``
markers (``{"name", "k0", "stamp_ns", "stages", …}``) before their first block.  The run's state (``idle``,
``playing``, ``finished``, ``stopped``, ``failed``) is published as a dict.

Everything the player needs from the outside — clocks, sleeping, waiting for an answer, the graph being ready,
publishing — goes through a :class:`PlayerHost`: the node gives it ROS publishers and the system clocks, a test a
fake clock (``test/test_trajectory_player.py``).  :func:`check_play_params` validates the parameters (a
:class:`~piezo_ff_ros.core.config.ConfigError` naming the field) and :func:`parse_trajectory` builds the trajectory
from its text or file.
"""
from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Protocol

import numpy as np


from .config import ConfigError
from .config.loader import safe_yaml
from .status import ERROR, OK, WARN
from .trajectories import Table, Trajectory, check_trajectory_peaks, from_dict
from .units import sample_period_ns

__all__ = ["PLAY_MODES", "MAX_BLOCK_SIZE", "PlaySettings", "PlayerHost", "TrajectoryPlayer", "check_play_params",
           "parse_trajectory"]

#: the two ways of playing
PLAY_MODES = ("realtime", "lockstep")
#: the largest block a player sends [samples] (the driver's default max_block)
MAX_BLOCK_SIZE = 20000
#: how long one wait for an answer lasts before the expiry and timeout are checked again [s]
_POLL_S = 0.1


def _is_number(value: object) -> bool:
    return not isinstance(value, bool) and isinstance(value, (int, float))


def check_play_params(values: Mapping[str, Any]) -> None:
    """Validate the play parameters present in ``values`` (any subset).

    Parameters
    ----------
    values : mapping
        Parameter name → value.  Checked: ``mode``, ``block_size``, ``window``, ``preview_s``, ``workspace_m``,
        ``sample_rate`` (its period a whole number of nanoseconds), ``lockstep_timeout``, ``ack_timeout`` and
        ``voltage_limit``; other names are ignored.

    Raises
    ------
    ConfigError
        Naming the first invalid field and why.
    """
    if "mode" in values and values["mode"] not in PLAY_MODES:
        raise ConfigError("mode", f"must be 'realtime' or 'lockstep', got {values['mode']!r}")
    for name in ("block_size", "window"):
        if name in values and (not isinstance(values[name], int) or values[name] < 1):
            raise ConfigError(name, f"must be an integer ≥ 1, got {values[name]!r}")
    if "block_size" in values and values["block_size"] > MAX_BLOCK_SIZE:
        raise ConfigError("block_size", f"must be ≤ {MAX_BLOCK_SIZE} (the driver's default max_block)")
    if "preview_s" in values and (not _is_number(values["preview_s"]) or not 0.0 <= values["preview_s"] <= 1.0):
        raise ConfigError("preview_s", f"must be a number of seconds in [0, 1], got {values['preview_s']!r}")
    if "workspace_m" in values and (not _is_number(values["workspace_m"])
                                    or not 0.0 <= values["workspace_m"] < math.inf):
        raise ConfigError("workspace_m",
                          f"must be a number of metres >= 0 (0: no check), got {values['workspace_m']!r}")
    for name in ("sample_rate", "lockstep_timeout", "ack_timeout", "voltage_limit"):
        if name in values and (not _is_number(values[name]) or not values[name] > 0):
            raise ConfigError(name, f"must be a number > 0, got {values[name]!r}")
    if "sample_rate" in values:   # stamps are t0 + k·period on a whole-nanosecond grid: another rate would drift
        try:
            sample_period_ns(values["sample_rate"])
        except ValueError as exc:
            raise ConfigError("sample_rate", str(exc).split(": ", 1)[-1]) from None


def parse_trajectory(text: str = "", file: str = "", sample_rate: float = 20000.0, workspace_m: float = 0.0,
                     voltage_limit: float | None = None) -> Trajectory:
    """The trajectory from spec text (JSON/YAML), a spec file or a table file, checked against the workspace.

    Parameters
    ----------
    text : str
        A :func:`~piezo_ff_ros.core.trajectories.from_dict` spec as JSON or YAML.
    file : str
        A spec file (YAML/JSON), or a table of samples (``.npy``, or ``.csv`` with a header of axis names) played
        sample-exactly at ``sample_rate``; wins over ``text`` when set.
    sample_rate : float
        Samples per second [Hz].
    workspace_m : float
        A trajectory beyond ±workspace_m [m] on any axis is refused (0: no check).
    voltage_limit : float, optional
        The bound [V] of segments marked ``input: voltage``.

    Returns
    -------
    Trajectory

    Raises
    ------
    ConfigError
        Naming the field (``trajectory``, ``trajectory_file``, ``trajectory.<key>``, ``workspace_m`` …).
    """
    traj = _parse(text, file, sample_rate)
    check_trajectory_peaks(traj, workspace_m, voltage_limit, fs=sample_rate)
    return traj


def _parse(text: str, file: str, sample_rate: float) -> Trajectory:
    if file:
        p = Path(file)
        if not p.is_file():
            raise ConfigError("trajectory_file", f"{file}: no such file")
        if p.suffix.lower() in (".npy", ".csv"):
            try:
                return Table(file=str(p), sample_rate=sample_rate)
            except ConfigError as exc:
                raise ConfigError(f"trajectory_file.{exc.field}", exc.reason) from None
        text = p.read_text()
    spec = safe_yaml(text, "trajectory") if text.strip() else None   # size/depth/alias limits: no crash, no stall
    if spec is None:
        raise ConfigError("trajectory", "empty")
    return from_dict(spec, prefix="trajectory")


@dataclass(frozen=True)
class PlaySettings:
    """How one run plays (read when it starts; see the module docstring).

    Parameters
    ----------
    mode : str
        ``realtime`` or ``lockstep``.
    block_size : int
        Samples per block.
    window : int
        Lockstep: blocks in flight at most.
    preview_s : float
        Play the trajectory this far ahead [s] (a plant with an input delay lands on time; exact, since a
        trajectory is a pure function of the sample index).
    loop : bool
        Start again at the end.
    lockstep_timeout : float
        Lockstep: no answer for this long while blocks are in flight fails the run [s]; also how long the start
        waits for the graph.
    ack_timeout : float
        Lockstep: a block not answered for this long is given up [s].
    """

    mode: str = "realtime"
    block_size: int = 200
    window: int = 4
    preview_s: float = 0.0
    loop: bool = False
    lockstep_timeout: float = 10.0
    ack_timeout: float = 5.0

    def __post_init__(self) -> None:
        check_play_params({"mode": self.mode, "block_size": self.block_size, "window": self.window,
                           "preview_s": self.preview_s, "lockstep_timeout": self.lockstep_timeout,
                           "ack_timeout": self.ack_timeout})

    @staticmethod
    def from_params(params: Mapping[str, Any]) -> "PlaySettings":
        """From the node's parameters (the fields above by name; others ignored).

        Parameters
        ----------
        params : mapping
            Parameter name → value.

        Returns
        -------
        PlaySettings
        """
        return PlaySettings(mode=str(params["mode"]), block_size=int(params["block_size"]),
                            window=int(params["window"]), preview_s=float(params["preview_s"]),
                            loop=bool(params["loop"]), lockstep_timeout=float(params["lockstep_timeout"]),
                            ack_timeout=float(params["ack_timeout"]))


class PlayerHost(Protocol):
    """What a :class:`TrajectoryPlayer` needs from where it runs (a node, a test's fake clock)."""

    def monotonic(self) -> float:
        """A monotonic clock [s] (pacing, acknowledgement expiry and timeouts)."""

    def wall_ns(self) -> int:
        """The wall clock [ns] (realtime stamps)."""

    def sleep(self, seconds: float) -> None:
        """Sleep (realtime pacing)."""

    def wait(self, cv: threading.Condition, seconds: float) -> None:
        """Wait on ``cv`` (held by the caller) for at most ``seconds``: an answer, a stop, or the time."""

    def wait_graph(self, timeout: float, lockstep: bool) -> None:
        """Return once the graph is ready to play; raise ``TimeoutError`` after ``timeout`` seconds."""

    def publish_reference(self, block: np.ndarray, axes: list[str], stamp_ns: int) -> None:
        """Send one reference block ``[N, axes]`` stamped with its first sample."""

    def publish_experiment(self, info: dict[str, Any]) -> None:
        """Announce a segment (an ``experiment`` marker)."""

    def publish_state(self, state: dict[str, Any]) -> None:
        """Publish the run's state."""

    def log(self, level: int, text: str) -> None:
        """One log line at ``level`` (:data:`~piezo_ff_ros.core.status.OK` info, ``WARN``, ``ERROR``)."""


class TrajectoryPlayer:
    """Plays trajectories on one stream (see the module docstring).

    Parameters
    ----------
    host : PlayerHost
        Clocks, waiting and publishing.
    period_ns : int
        The sample period [ns].
    t0_ns : int
        Stamp of sample index 0 (rounded down to the sample grid); 0: the wall clock now.
    """

    def __init__(self, host: PlayerHost, period_ns: int, t0_ns: int = 0) -> None:
        if isinstance(period_ns, bool) or not isinstance(period_ns, int) or period_ns < 1:
            raise ValueError(f"period_ns: expected an integer ≥ 1, got {period_ns!r}")
        self.host = host
        self.period_ns = period_ns
        t0 = int(t0_ns) or host.wall_ns()
        self.t0_ns = t0 // period_ns * period_ns
        self.k_stream = 0                         #: stream index of the next block (never goes back)
        self.unanswered = 0                       #: lockstep blocks given up (never answered)
        self.state: dict[str, Any] = {"state": "idle"}
        self._cv = threading.Condition()
        self._inflight: dict[int, float] = {}     # lockstep: stamp → when sent (monotonic)
        self._last_ack = host.monotonic()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._ended_by: threading.Thread | None = None   # the play thread that has published its run's end
        self._run_mode: str | None = None         # the mode of the run being played (the parameter may change)

    # -- state -------------------------------------------------------------------------------------------------
    @property
    def stopping(self) -> bool:
        """True once :meth:`stop` was called (until the next start)."""
        return self._stop.is_set()

    @property
    def playing(self) -> bool:
        """True while a run started by :meth:`start` is being played."""
        return self._thread is not None and self._thread.is_alive()

    @property
    def in_flight(self) -> int:
        """Lockstep blocks sent and not answered yet."""
        with self._cv:
            return len(self._inflight)

    def set_state(self, state: str, mode: str | None = None, **extra: Any) -> None:
        """Publish ``{"state", "mode", "k", "unanswered_blocks", **extra}``.

        Parameters
        ----------
        state : str
            ``idle``, ``playing``, ``finished``, ``stopped`` or ``failed``.
        mode : str, optional
            The mode to report when no run has started yet (else the run's).
        **extra
            More keys.
        """
        self.state = {"state": state, "mode": self._run_mode or mode, "k": int(self.k_stream),
                      "unanswered_blocks": self.unanswered, **extra}
        if state in ("finished", "stopped", "failed"):
            self._ended_by = threading.current_thread()   # that run's thread only winds up from here (see start)
        self.host.publish_state(self.state)

    # -- start / stop ------------------------------------------------------------------------------------------
    def start(self, traj: Trajectory, sample_rate: float, settings: PlaySettings) -> tuple[bool, str]:
        """Play ``traj`` in a thread of its own (:meth:`play`).

        Parameters
        ----------
        traj : Trajectory
            What to play.
        sample_rate : float
            Samples per second [Hz].
        settings : PlaySettings
            How.

        Returns
        -------
        (bool, str)
            Whether it started, and a line for the caller.
        """
        if self.playing and self._ended_by is self._thread:
            # the run has ended and said so: a client may start the next one the moment it hears it, while the
            # play thread only winds up (its last log line; long on a loaded host)
            assert self._thread is not None
            self._thread.join(timeout=5.0)
        if self.playing:
            return False, "already playing (call ~/stop first)"
        self._stop.clear()
        self._thread = threading.Thread(target=self.play, args=(traj, sample_rate, settings),
                                        name="trajectory-play", daemon=True)
        self._thread.start()
        return True, f"playing {type(traj).__name__} from sample {self.k_stream}"

    def stop(self, join: bool = True) -> None:
        """Stop the run at its next block (waiting for its thread up to 5 s when ``join``)."""
        self._stop.set()
        with self._cv:
            self._cv.notify_all()
        if join and self._thread is not None:
            self._thread.join(timeout=5.0)

    # -- answers -----------------------------------------------------------------------------------------------
    def on_ack(self, stamp_ns: int, n_samples: int) -> None:
        """A ``displacement`` block came back: ``n_samples`` samples from ``stamp_ns``.

        The block sent with that stamp is answered; blocks stamped before it never will be (dropped as late, or
        their node died) and are given up; the stream index moves past the answered samples (the driver may have
        published samples of its own, a safe-state ramp: their indices are never reused).
        """
        end_k = (stamp_ns - self.t0_ns) // self.period_ns + int(n_samples)
        with self._cv:
            self._inflight.pop(stamp_ns, None)
            self._give_up([s for s in self._inflight if s < stamp_ns], "the driver answered a later block")
            self._last_ack = self.host.monotonic()
            self.k_stream = max(self.k_stream, end_k) if end_k > 0 else self.k_stream
            self._cv.notify_all()

    def _give_up(self, stamps: list[int], why: str) -> None:
        """Lockstep (under ``_cv``): stop waiting for these blocks; counted, WARN, in the state."""
        if not stamps:
            return
        for s in stamps:
            self._inflight.pop(s, None)
        self.unanswered += len(stamps)
        self.host.log(WARN, f"lockstep: {len(stamps)} block(s) never answered ({why}), given up: "
                            f"{self.unanswered} so far")
        self.state["unanswered_blocks"] = self.unanswered
        self.host.publish_state(self.state)

    def _expire(self, ack_timeout: float) -> None:
        now = self.host.monotonic()
        self._give_up([s for s, t in self._inflight.items() if now - t > ack_timeout],
                      f"no displacement within ack_timeout {ack_timeout} s")

    def _wait_answers(self, until_below: int, settings: PlaySettings, why: str) -> None:
        """Lockstep (under ``_cv``): wait until fewer than ``until_below`` blocks are in flight (or a stop);
        ``TimeoutError`` when nothing came back for ``lockstep_timeout``."""
        while len(self._inflight) >= until_below and not self._stop.is_set():
            self.host.wait(self._cv, _POLL_S)
            self._expire(settings.ack_timeout)
            if self.host.monotonic() - self._last_ack > settings.lockstep_timeout:
                raise TimeoutError(why.format(n=len(self._inflight), timeout=settings.lockstep_timeout))

    # -- play --------------------------------------------------------------------------------------------------
    def _marker(self, name: str, k0: int, meta: Mapping[str, Any], k1: int | None = None) -> None:
        info = {"name": name, "k0": int(k0), "stamp_ns": int(self.t0_ns + k0 * self.period_ns),
                "stages": meta.get("stages"), **{k: v for k, v in meta.items() if k != "stages"}}
        if k1 is not None:   # the segment's own end: samples a clocked device holds after it are not part of it
            info["k1"] = int(k1)
        self.host.publish_experiment(info)

    def play(self, traj: Trajectory, sample_rate: float, settings: PlaySettings) -> None:
        """Play ``traj`` until it ends (again and again with ``loop``) or :meth:`stop`; the state says how it ended.

        Parameters
        ----------
        traj : Trajectory
            What to play.
        sample_rate : float
            Samples per second [Hz].
        settings : PlaySettings
            How.
        """
        host, fs = self.host, float(sample_rate)
        mode, n_blk, window = settings.mode, settings.block_size, settings.window
        self._run_mode = mode
        preview = int(round(settings.preview_s * fs))  # samples played ahead
        total = traj.n_samples(fs)
        segments = getattr(traj, "segments", None)
        segs = segments(fs) if segments is not None else []
        axes = list(traj.axes)
        blocks = 0
        try:
            host.wait_graph(settings.lockstep_timeout, mode == "lockstep")
            while True:
                with self._cv:
                    if mode == "realtime":  # stamps follow the wall clock (exact latency measurement)
                        self.k_stream = max(self.k_stream, (host.wall_ns() - self.t0_ns) // self.period_ns)
                    start = self.k_stream
                self.set_state("playing", start=int(start), total=None if math.isinf(total) else int(total))
                k = 0
                next_wall = host.monotonic()
                seg_i = 0
                while (math.isinf(total) or k < total) and not self._stop.is_set():
                    n = n_blk if math.isinf(total) else int(min(n_blk, total - k))
                    while seg_i < len(segs) and segs[seg_i].start < k + n:
                        s = segs[seg_i]
                        self._marker(s.name, start + s.start, s.meta,
                                     None if math.isinf(s.stop) else start + int(s.stop))
                        seg_i += 1
                    block = traj.block(k + preview, n, fs)
                    kk = start + k
                    stamp = self.t0_ns + kk * self.period_ns
                    if mode == "realtime":
                        delay = next_wall - host.monotonic()
                        if delay > 0:
                            host.sleep(delay)
                        next_wall += n / fs
                    else:
                        with self._cv:
                            if not self._inflight:   # the timeout runs while something is in flight
                                self._last_ack = host.monotonic()
                            self._wait_answers(window, settings,
                                               "lockstep: no displacement for {timeout} s (is the driver running?)")
                            self._inflight[stamp] = host.monotonic()
                    host.publish_reference(block, axes, stamp)
                    with self._cv:
                        self.k_stream = max(self.k_stream, kk + n)
                    k += n
                    blocks += 1
                if mode == "lockstep":  # the run is finished when its last displacement came back
                    with self._cv:
                        self._last_ack = host.monotonic()
                        self._wait_answers(1, settings, "lockstep: {n} block(s) never answered")
                if self._stop.is_set() or not settings.loop:
                    break
            self.set_state("stopped" if self._stop.is_set() else "finished", blocks=blocks)
            host.log(OK, f"trajectory {self.state['state']}: {blocks} blocks")
        except TimeoutError as exc:
            host.log(ERROR, str(exc))
            with self._cv:
                self._inflight.clear()
            self.set_state("failed", error=str(exc), blocks=blocks)
        except Exception as exc:  # noqa: BLE001 - context shut down while stopping, or a bad trajectory
            if not self._stop.is_set():
                host.log(ERROR, f"trajectory: {exc}")
                try:
                    self.set_state("failed", error=str(exc), blocks=blocks)
                except Exception:  # noqa: BLE001
                    pass
