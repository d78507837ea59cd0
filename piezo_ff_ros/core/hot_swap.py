"""Runtime reconfiguration of the compensator cascade without a jump in its output, and re-synchronisation of its
states on the voltage actually applied (pure, no ROS).

:class:`HotSwapCascade` runs one :class:`~piezo_ff_ros.core.compensators.cascade.CompensatorCascade` and replaces it
by a new one **only between blocks**:

1. ``request(cfg)`` builds the new cascade — synchronously when that is cheap, in a worker thread when it needs an
   H∞ synthesis (the old cascade keeps running meanwhile; a newer request supersedes an older one still building;
   a failed build leaves the old cascade and records the error).  H∞ designs are cached by (G_L, weights), so
   switching stages on/off never resynthesises.
2. At the next block boundary (``process`` or ``poll``) the new cascade takes over **bumplessly**:

   - state transfer through each stage's own realisation (``continue_from``, :mod:`piezo_ff_ros.core.stage`): the
     hysteresis inverse keeps ``h`` and the last voltage (they describe the plant); a linear stage's modes that
     exist in both realisations keep their exact state (same input history), new modes are fitted to reproduce
     the old stage's free response; a newly enabled linear stage starts at its steady state for the signal it
     was last fed;
   - crossfade: during ``crossfade_samples`` both cascades run and the output moves linearly from the old one's
     to the new one's.  After every crossfade block the plant-side states (hysteresis, creep) of *every* cascade
     in the fade are re-derived from the mixed voltage actually sent, so that the new cascade ends the fade
     describing the plant; a second swap during a fade fades from the running mix (the first old cascade keeps
     fading out), not from the newest cascade alone.

3. Re-synchronisation on the applied voltage: blocks processed with their first-sample index (``process(block,
   k0)``) are kept as *in flight* until the driver reports the voltage it applied for those samples
   (:meth:`applied`).  When the applied voltage is what was commanded, nothing changes (bit-identical output).
   When it differs (clamps, slew limits, a safe ramp, held samples after a stall, dropped late blocks, a gap),
   the hysteresis and creep states are rebuilt from the last confirmed state by following the applied voltage
   (a gap counts as the last voltage held), then the commands still in flight, so that the inverse models again
   describe the plant.

Swapping to an identical configuration is therefore invisible (bit-identical output).
"""
from __future__ import annotations

import copy
import json
import threading
from collections import deque
from dataclasses import dataclass
from typing import Any, Callable, Union

import numpy as np

from .compensators.cascade import CompensatorCascade
from .config import PiezoConfig
from .stage import StageState

#: builds a cascade for a configuration (and an optional controller / H∞ design)
CascadeFactory = Callable[..., CompensatorCascade]
#: the plant-side state of a cascade (``CompensatorCascade.state(PLANT_STAGES)``)
_PlantState = dict[str, StageState]

__all__ = ["HotSwapCascade", "synthesis_key"]


def synthesis_key(cfg: PiezoConfig) -> str:
    """What an H∞ design depends on: G_L, the weights, the order and the sample period."""
    d = cfg.to_dict(length_unit="m")
    vib = {k: v for k, v in d["vibration"].items() if k != "controller"}
    return json.dumps({"G_L": d["dynamics"], "vib": vib}, sort_keys=True)


def _lin_steady_gain(A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray) -> np.ndarray:
    n = A.shape[0]
    if n == 0:
        return D.copy()
    g: np.ndarray = C @ np.linalg.solve(np.eye(n) - A, B) + D
    return g


def _default_factory(cfg: PiezoConfig, controller: Any = None) -> CompensatorCascade:
    return CompensatorCascade(cfg, controller=controller)


class _Pending:
    def __init__(self, version: int, cfg: PiezoConfig) -> None:
        self.version = version
        self.cfg = cfg
        self.cascade: CompensatorCascade | None = None
        self.error: str | None = None
        self.done = threading.Event()


class _Fade:
    """Crossfade from ``old`` (a cascade or a running fade) to ``new`` over ``length`` samples."""

    def __init__(self, old: Union[CompensatorCascade, "_Fade"], new: CompensatorCascade, length: int) -> None:
        self.old, self.new, self.length, self.done = old, new, int(length), 0

    def leaves(self) -> list[CompensatorCascade]:
        olds = self.old.leaves() if isinstance(self.old, _Fade) else [self.old]
        return olds + [self.new]

    def mix(self, signals: list[np.ndarray], n: int) -> np.ndarray:
        """Mix of the leaves' signals (in :meth:`leaves` order) over the next ``n`` samples (no advance)."""
        k = len(signals) - 1
        y_old = self.old.mix(signals[:k], n) if isinstance(self.old, _Fade) else signals[0]
        y_new = signals[k]
        w = np.minimum((self.done + 1 + np.arange(n)) / self.length, 1.0)[:, None]
        y: np.ndarray = y_old + w * (y_new - y_old)
        return y

    def advance(self, n: int) -> None:
        self.done += n
        if isinstance(self.old, _Fade):
            self.old.advance(n)
            if self.old.finished:
                self.old = self.old.new   # the inner fade is over: its newest cascade alone remains

    @property
    def finished(self) -> bool:
        return self.done >= self.length


#: the voltage crossfade (hysteresis stage switched or changed) re-synchronises every this many samples
_FADE_CHUNK = 8


@dataclass
class _InFlight:
    k0: int
    u: np.ndarray                 # the voltages sent for samples k0 … k0 + N − 1
    cascade: CompensatorCascade   # the cascade whose plant-side state ``state_after`` is
    state_after: _PlantState      # plant-side state after these samples, had they been applied as sent


def _follow_hold(cascade: CompensatorCascade, n: int, axes: int) -> None:
    """``cascade``'s plant-side states follow ``n`` samples of its last voltage held (0 V before any)."""
    last = cascade.last_voltage()
    cascade.follow_applied(np.tile(last if last is not None else np.zeros(axes), (n, 1)))


class HotSwapCascade:
    """A compensator cascade that can be reconfigured while it runs, and re-synchronised on the applied voltage.

    Parameters
    ----------
    cfg : PiezoConfig
        Initial configuration (built synchronously).
    crossfade_samples : int
        Length of the output crossfade at a swap (0 = state transfer only).
    factory : callable ``(cfg, controller) -> CompensatorCascade``, optional
        Builds a cascade (default :class:`CompensatorCascade`); tests inject slow or failing factories.
    max_inflight_samples : int
        Most samples kept in flight awaiting :meth:`applied`; beyond, tracking restarts (bounded memory when no
        applied voltage comes back).
    """

    def __init__(self, cfg: PiezoConfig, crossfade_samples: int = 200,
                 factory: CascadeFactory | None = None, max_inflight_samples: int = 400_000) -> None:
        self.factory: CascadeFactory = factory or _default_factory
        self.crossfade_samples = int(crossfade_samples)
        self._designs: dict[str, object] = {}
        self._lock = threading.Lock()
        self.active = self._build(cfg)
        self.cfg = cfg
        self.version = 1            #: version of the active configuration
        self._next_version = 2
        self.swaps = 0
        self.failed_builds = 0
        self.last_error = ""
        self._pending: _Pending | None = None
        self._fade: _Fade | None = None
        self._running = False                 # a block was processed since construction/reset
        self._last_in: np.ndarray | None = None
        self._last_taps: dict[str, np.ndarray] | None = None
        # re-synchronisation on the applied voltage
        self._conf: tuple[int, CompensatorCascade, _PlantState] | None = None   # (k, cascade, plant-side state): consistent with applied samples < k
        self._inflight: deque[_InFlight] = deque()
        self._inflight_samples = 0
        self.max_inflight_samples = int(max_inflight_samples)
        #: applied voltages within this of the command count as applied as commanded [V] (a driver's slew limiter
        #: writes ``u_prev + (u − u_prev)``, which may differ from ``u`` in the last bit)
        self.match_tolerance = 1e-9
        self._last_applied: np.ndarray | None = None
        self.resyncs = 0            #: re-synchronisations on an applied voltage that differed from the command
        self.applied_blocks = 0     #: applied blocks that matched the command exactly
        self.applied_ignored = 0    #: applied blocks for samples already accounted for (or not tracked)

    # -- building ------------------------------------------------------------------------------------------------
    def _controller_for(self, cfg: PiezoConfig) -> object | None:
        if not cfg.cascade.vibration or cfg.vibration.controller is not None:
            return None
        with self._lock:
            return self._designs.get(synthesis_key(cfg))

    def needs_background(self, cfg: PiezoConfig) -> bool:
        """True when building ``cfg`` means an H∞ synthesis (not in the design cache)."""
        return bool(cfg.cascade.vibration and cfg.vibration.controller is None
                    and self._controller_for(cfg) is None)

    def _build(self, cfg: PiezoConfig) -> CompensatorCascade:
        casc = self.factory(cfg, controller=self._controller_for(cfg))
        design = getattr(casc, "design", None)
        if design is not None and cfg.vibration.controller is None:
            with self._lock:
                self._designs[synthesis_key(cfg)] = design
        # compile/warm the kernels off the hot path (a throw-away copy, state untouched): every way the live path
        # runs a cascade — fused, stage by stage with taps, the front alone (crossfade), following the applied
        # voltage (re-synchronisation) — since a stage's loops are compiled for its structure on first use
        z = np.zeros((1, cfg.n_axes))
        warm = copy.deepcopy(casc)
        warm.process(z)
        warm.process_with_taps(z)
        warm.process_front(z)
        if warm.can_follow:
            warm.follow_applied(z)
        return casc

    def request(self, cfg: PiezoConfig, background: bool | None = None) -> int:
        """Ask for ``cfg``; returns its version.  It becomes active at a block boundary once built."""
        version = self._next_version
        self._next_version += 1
        pend = _Pending(version, cfg)
        self._pending = pend  # supersedes any older request
        if background is None:
            background = self.needs_background(cfg)

        def work() -> None:
            try:
                pend.cascade = self._build(cfg)
            except Exception as exc:  # noqa: BLE001 - any build failure keeps the old cascade
                pend.error = str(exc) or type(exc).__name__
            pend.done.set()

        if background:
            threading.Thread(target=work, name=f"cascade-build-v{version}", daemon=True).start()
        else:
            work()
        return version

    @property
    def pending_version(self) -> int | None:
        """Version of the configuration being built off the hot path (None: nothing pending)."""
        p = self._pending
        return p.version if p is not None else None

    @property
    def pending_cfg(self) -> PiezoConfig | None:
        """The configuration being built off the hot path (None: nothing pending)."""
        p = self._pending
        return p.cfg if p is not None else None

    def wait_pending(self, timeout: float | None = None) -> bool:
        """Block until the pending build (if any) finished (for tests and tools, not the hot path)."""
        p = self._pending
        return True if p is None else p.done.wait(timeout)

    # -- swapping ------------------------------------------------------------------------------------------------
    def poll(self) -> bool:
        """At a block boundary: make a finished build active (True if a swap happened)."""
        p = self._pending
        if p is None or not p.done.is_set():
            return False
        self._pending = None
        if p.error is not None:
            self.failed_builds += 1
            self.last_error = f"configuration v{p.version} not applied: {p.error}"
            return False
        assert p.cascade is not None, "a build that raised nothing has set its cascade"
        self._swap(p.cascade, p.cfg, p.version)
        return True

    def _swap(self, new: CompensatorCascade, cfg: PiezoConfig, version: int) -> None:
        old = self.active
        if self._running:
            self._transfer_state(old, new)
            if self.crossfade_samples > 0:
                # a swap during a fade fades out the running mix, not just the newest cascade
                self._fade = _Fade(self._fade if self._fade is not None else old, new, self.crossfade_samples)
        self.active, self.cfg, self.version = new, cfg, version
        self.swaps += 1

    def _transfer_state(self, old: CompensatorCascade, new: CompensatorCascade) -> None:
        same_order = old.cfg.cascade.order == new.cfg.cascade.order
        taps = self._last_taps or {}
        r = self._last_in
        signal = None if r is None else r.copy()    # steady-state input to the next stage of the new chain
        for name, tap in (("vibration", "yl"), ("creep", "yh"), ("hysteresis", "u")):
            st_new = getattr(new, name)
            st_old = getattr(old, name)
            if st_new is None:
                continue
            if st_old is not None and (same_order or name == "hysteresis"):
                if name == "hysteresis":
                    st_new.continue_from(st_old)
                else:   # the last input of the linear system inside: C(s) sees Y_R, the creep inverse's Cr sees Y_H
                    st_new.continue_from(st_old, signal if name == "vibration" else taps.get("yh"))
                signal = taps.get(tap, signal)
            elif name != "hysteresis" and signal is not None:
                signal = _settle(name, st_new, signal)

    def reset(self) -> None:
        """All states to rest; a finished pending configuration is applied without crossfade."""
        self._fade = None
        self._running = False
        self.poll()
        self.active.reset()
        self._last_in = None
        self._last_taps = None
        self._conf = None
        self._inflight.clear()
        self._inflight_samples = 0
        self._last_applied = None

    # -- streaming -----------------------------------------------------------------------------------------------
    def process(self, block: np.ndarray, k0: int | None = None) -> np.ndarray:
        """One block ``Y_R [m] → U [V]`` (swaps first if a new configuration is ready).

        ``k0`` (index of the block's first sample) keeps the block in flight for :meth:`applied`.
        """
        self.poll()
        x = np.ascontiguousarray(block, dtype=float)
        track = k0 is not None and self.active.can_follow and x.shape[0] > 0
        if track and k0 is not None:   # (track implies k0 is not None)
            end = self._inflight[-1].k0 + len(self._inflight[-1].u) if self._inflight else \
                (self._conf[0] if self._conf is not None else None)
            resumed = end is not None and 0 < k0 - end <= self.max_inflight_samples - self._inflight_samples
            if end != k0 and not resumed:   # first block, or the reference stream restarted / jumped back
                self._inflight.clear()
                self._inflight_samples = 0
                self._conf = (k0, self.active, self.active.state(CompensatorCascade.PLANT_STAGES))
        if self._fade is not None:
            y, taps = self._process_fading(x, self._fade)
        else:
            y, taps = self.active.process_with_taps(x)
        if x.shape[0]:
            self._running = True
            self._last_in = x[-1].copy()
            self._last_taps = {k: v[-1].copy() for k, v in taps.items()} if self.active.cfg.cascade.order == "paper" \
                else None
        if track and k0 is not None:   # (track implies k0 is not None)
            self._inflight.append(_InFlight(k0, y.copy(), self.active,
                                            self.active.state(CompensatorCascade.PLANT_STAGES)))
            self._inflight_samples += x.shape[0]
            if self._inflight_samples > self.max_inflight_samples:  # nothing comes back: bounded memory, restart
                self._inflight.clear()
                self._inflight_samples = 0
                self._conf = None
        return y

    def _process_fading(self, x: np.ndarray, fade: _Fade) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        active = self.active
        leaves = fade.leaves()
        n = x.shape[0]
        shared = active.hysteresis
        if shared is not None and all(_same_hysteresis(c, active) for c in leaves):
            # fade the hysteresis inverse's input Y_H and run the one inverse: it stays exactly on the voltage
            # sent; every creep inverse follows the mixed Y_H (what the plant's creep receives)
            pre = [c.creep.state() if c.creep is not None else None for c in leaves]
            fronts = [c.process_front(x) for c in leaves]
            yh = fade.mix([f[0] for f in fronts], n)
            y = shared.process(yh)
            hyst = shared.state()
            for c, p, (own, _) in zip(leaves, pre, fronts):
                if c is not active and c.hysteresis is not None:   # (not None: _same_hysteresis)
                    c.hysteresis.load_state(hyst)
                if c.creep is not None and p is not None and not np.array_equal(own, yh):
                    c.creep.load_state(p)
                    c.creep.follow(yh)
            taps = {**fronts[-1][1], "yh": yh, "u": y}
            fade.advance(n)
        else:
            # the hysteresis stage is switched or changed: fade the voltages, in short chunks after which every
            # cascade's plant-side states follow the voltage sent
            parts, tap_parts = [], []
            for i in range(0, n, _FADE_CHUNK):
                xc = x[i:i + _FADE_CHUNK]
                leaves = fade.leaves()
                before = [c.state(CompensatorCascade.PLANT_STAGES) for c in leaves]
                outs = []
                for c in leaves[:-1]:
                    outs.append(c.process(xc))
                y_new, t_new = active.process_with_taps(xc)
                outs.append(y_new)
                yc = fade.mix(outs, xc.shape[0])
                for c, st, o in zip(leaves, before, outs):
                    if c.can_follow and not np.array_equal(o, yc):
                        c.load_state(st)
                        c.follow_applied(yc)
                parts.append(yc)
                tap_parts.append({**t_new, "u": yc})
                fade.advance(xc.shape[0])
                if fade.finished:
                    break
            done = sum(p.shape[0] for p in parts)
            if done < n:  # the fade ended inside the block: the rest is the new cascade's alone
                y_rest, t_rest = active.process_with_taps(x[done:])
                parts.append(y_rest)
                tap_parts.append(t_rest)
            y = np.vstack(parts)
            taps = {k: np.vstack([t[k] for t in tap_parts]) for k in tap_parts[-1]}
        if fade.finished:
            self._fade = None
        return y, taps

    # -- re-synchronisation on the applied voltage ---------------------------------------------------------------
    def applied(self, k0: int, u: np.ndarray) -> str:
        """The driver applied the voltages ``u`` to samples ``k0 …``; returns ``"match"`` (as commanded),
        ``"resync"`` (states rebuilt from the applied voltage) or ``"ignored"`` (not tracked / already accounted)."""
        u = np.ascontiguousarray(u, dtype=float)
        if self._conf is None or u.shape[0] == 0:
            self.applied_ignored += 1
            return "ignored"
        k_conf, casc, st = self._conf
        if k0 + u.shape[0] <= k_conf:
            self.applied_ignored += 1
            return "ignored"
        if k0 < k_conf:
            u, k0 = u[k_conf - k0:], k_conf
        if k0 - k_conf > self.max_inflight_samples:
            # no amplifier held its voltage that long between two blocks it reported (a stray stamp): following
            # it would allocate the whole hold; the tracking restarts with the next block sent instead
            self._inflight.clear()
            self._inflight_samples = 0
            self._conf = None
            self.applied_ignored += 1
            return "ignored"
        self._last_applied = u[-1].copy()
        head = self._inflight[0] if self._inflight else None
        if head is not None and k0 == k_conf == head.k0 and head.u.shape == u.shape and \
                np.max(np.abs(head.u - u)) <= self.match_tolerance:
            self._inflight.popleft()
            self._inflight_samples -= u.shape[0]
            self._conf = (k0 + u.shape[0], head.cascade, head.state_after)
            self.applied_blocks += 1
            return "match"
        self._resync(k_conf, casc, st, k0, u)
        self.resyncs += 1
        return "resync"

    def _resync(self, k_conf: int, casc: CompensatorCascade, st: _PlantState, k0: int, u: np.ndarray) -> None:
        c = copy.deepcopy(casc)
        c.load_state(st)
        if k0 > k_conf:  # samples nobody reported: the amplifier held its last voltage
            _follow_hold(c, k0 - k_conf, u.shape[1])
        c.follow_applied(u)
        k_end = k0 + u.shape[0]
        self._conf = (k_end, c, c.state(CompensatorCascade.PLANT_STAGES))
        rest: deque[_InFlight] = deque()
        reached = k_end
        for rec in self._inflight:                    # the commands still in flight, as they will be applied
            end = rec.k0 + len(rec.u)
            if end <= k_end:
                continue
            sent = rec.u[max(0, k_end - rec.k0):]
            follower = copy.deepcopy(c) if not rest else rest[-1].cascade
            if not rest:
                follower.load_state(self._conf[2])
            if rec.k0 > reached:   # a gap in the stream sent (a stall): the amplifier holds its last voltage
                _follow_hold(follower, rec.k0 - reached, sent.shape[1])
            follower.follow_applied(sent)
            reached = end
            rest.append(_InFlight(max(rec.k0, k_end), sent, follower, follower.state(CompensatorCascade.PLANT_STAGES)))
        self._inflight = rest
        self._inflight_samples = sum(len(r.u) for r in rest)
        final = rest[-1] if rest else None
        src = copy.deepcopy(final.cascade if final else c)
        src.load_state(final.state_after if final else self._conf[2])
        self._fade = None   # the applied voltage decides now: no mix of cascades that no longer describe the plant
        if src.cfg == self.active.cfg:
            self.active.load_state(src.state(CompensatorCascade.PLANT_STAGES))
        else:
            for name in CompensatorCascade.PLANT_STAGES:
                new, old = getattr(self.active, name), getattr(src, name)
                if new is not None and old is not None:
                    new.continue_from(old)

    @property
    def crossfading(self) -> bool:
        """True while the output crossfades from the old cascade to the new one."""
        return self._fade is not None

    def status(self) -> dict[str, Any]:
        """Counters and versions for ``/diagnostics``."""
        return {"config_version": self.version, "pending_version": self.pending_version, "swaps": self.swaps,
                "failed_builds": self.failed_builds, "crossfading": self.crossfading, "last_error": self.last_error,
                "resyncs": self.resyncs, "applied_blocks": self.applied_blocks,
                "in_flight_blocks": len(self._inflight)}


def _same_hysteresis(c: CompensatorCascade, active: CompensatorCascade) -> bool:
    """Both cascades end in the same hysteresis inverse (paper order): it can be shared through a fade."""
    a, b = c.cfg, active.cfg
    return (a.cascade.order == b.cascade.order == "paper" and c.hysteresis is not None
            and active.hysteresis is not None and a.hysteresis == b.hysteresis
            and a.cascade.hysteresis_loop == b.cascade.hysteresis_loop
            and a.cascade.respect_limits == b.cascade.respect_limits and a.limits == b.limits and a.dt == b.dt)


def _settle(name: str, st: Any, u: np.ndarray) -> np.ndarray:
    """Put a linear stage at its steady state for the constant input ``u``; return its steady output."""
    if name == "vibration":
        ss = st.ss
        st.filter.settle_to(u)
        y: np.ndarray = _lin_steady_gain(ss.A, ss.B, ss.C, ss.D) @ u
        return y
    # creep compensator: yh = K⁻¹(yl − C x), x = (I − A)⁻¹ B yh  ⇒  yh = (K + C (I − A)⁻¹ B)⁻¹ yl
    ss = st.ss
    K = np.linalg.inv(st.Kinv)
    n = ss.n_states
    G = ss.C @ np.linalg.solve(np.eye(n) - ss.A, ss.B) if n else np.zeros_like(K)
    yh: np.ndarray = np.linalg.solve(K + G, u)
    if n:
        st.x[:] = np.linalg.solve(np.eye(n) - ss.A, ss.B @ yh)
    return yh
