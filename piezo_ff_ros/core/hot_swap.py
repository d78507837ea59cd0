"""Runtime reconfiguration of the compensator cascade without a jump in its output (pure, no ROS).

:class:`HotSwapCascade` runs one :class:`~piezo_ff_ros.core.compensators.cascade.CompensatorCascade` and replaces it
by a new one **only between blocks**:

1. ``request(cfg)`` builds the new cascade — synchronously when that is cheap, in a worker thread when it needs an
   H∞ synthesis (the old cascade keeps running meanwhile; a newer request supersedes an older one still building;
   a failed build leaves the old cascade and records the error).  H∞ designs are cached by (G_L, weights), so
   switching stages on/off never resynthesises.
2. At the next block boundary (``process`` or ``poll``) the new cascade takes over **bumplessly**:

   - state transfer: a stage whose parameters did not change continues from the old stage's exact state; a changed
     hysteresis stage inherits the old ``h`` and last voltage (h estimates the plant's own state); a changed or newly
     enabled linear stage starts at its steady state for the signal it was last fed (no start-up transient);
   - crossfade: during ``crossfade_samples`` both cascades run and the output moves linearly from the old one's
     to the new one's, so whatever differences remain are spread over the window instead of a step.

Swapping to an identical configuration is therefore invisible (bit-identical output).
"""
from __future__ import annotations

import copy
import json
import threading
from typing import Callable

import numpy as np

from .compensators.cascade import CompensatorCascade
from .config import PiezoConfig

__all__ = ["HotSwapCascade", "synthesis_key"]


def synthesis_key(cfg: PiezoConfig) -> str:
    """What an H∞ design depends on: G_L, the weights, the order and the sample period."""
    d = cfg.to_dict(length_unit="m")
    vib = {k: v for k, v in d["vibration"].items() if k != "controller"}
    return json.dumps({"G_L": d["dynamics"], "vib": vib}, sort_keys=True)


def _lin_steady_gain(A, B, C, D):
    n = A.shape[0]
    if n == 0:
        return D.copy()
    return C @ np.linalg.solve(np.eye(n) - A, B) + D


class _Pending:
    def __init__(self, version: int, cfg: PiezoConfig):
        self.version = version
        self.cfg = cfg
        self.cascade: CompensatorCascade | None = None
        self.error: str | None = None
        self.done = threading.Event()


class HotSwapCascade:
    """A compensator cascade that can be reconfigured while it runs.

    Parameters
    ----------
    cfg : PiezoConfig
        Initial configuration (built synchronously).
    crossfade_samples : int
        Length of the output crossfade at a swap (0 = state transfer only).
    factory : callable ``(cfg, controller) -> CompensatorCascade``, optional
        Builds a cascade (default :class:`CompensatorCascade`); tests inject slow or failing factories.
    """

    def __init__(self, cfg: PiezoConfig, crossfade_samples: int = 200,
                 factory: Callable | None = None):
        self.factory = factory or (lambda c, controller=None: CompensatorCascade(c, controller=controller))
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
        self._fade: tuple | None = None       # (old cascade, samples done)
        self._running = False                 # a block was processed since construction/reset
        self._last_in: np.ndarray | None = None
        self._last_taps: dict | None = None

    # -- building ------------------------------------------------------------------------------------------------
    def _controller_for(self, cfg: PiezoConfig):
        if not cfg.cascade.vibration or cfg.vibration.controller is not None:
            return None
        with self._lock:
            return self._designs.get(synthesis_key(cfg))

    def needs_background(self, cfg: PiezoConfig) -> bool:
        """True when building ``cfg`` means an H∞ synthesis (not in the design cache)."""
        return (cfg.cascade.vibration and cfg.vibration.controller is None
                and self._controller_for(cfg) is None)

    def _build(self, cfg: PiezoConfig) -> CompensatorCascade:
        casc = self.factory(cfg, controller=self._controller_for(cfg))
        design = getattr(casc, "design", None)
        if design is not None and cfg.vibration.controller is None:
            with self._lock:
                self._designs[synthesis_key(cfg)] = design
        # compile/warm the kernels off the hot path (a throw-away copy, state untouched)
        copy.deepcopy(casc).process(np.zeros((1, cfg.n_axes)))
        return casc

    def request(self, cfg: PiezoConfig, background: bool | None = None) -> int:
        """Ask for ``cfg``; returns its version.  It becomes active at a block boundary once built."""
        version = self._next_version
        self._next_version += 1
        pend = _Pending(version, cfg)
        self._pending = pend  # supersedes any older request
        if background is None:
            background = self.needs_background(cfg)

        def work():
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
        p = self._pending
        return p.version if p is not None else None

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
        self._swap(p.cascade, p.cfg, p.version)
        return True

    def _swap(self, new: CompensatorCascade, cfg: PiezoConfig, version: int) -> None:
        old = self.active
        if self._running:
            self._transfer_state(old, new)
            if self.crossfade_samples > 0:
                self._fade = (old, 0)
        self.active, self.cfg, self.version = new, cfg, version
        self.swaps += 1

    def _transfer_state(self, old: CompensatorCascade, new: CompensatorCascade) -> None:
        same_order = old.cfg.cascade.order == new.cfg.cascade.order == "paper"
        taps = self._last_taps or {}
        r = self._last_in
        signal = None if r is None else r.copy()    # steady-state input to the next stage of the new chain
        for name, tap in (("vibration", "yl"), ("creep", "yh"), ("hysteresis", "u")):
            st_new = getattr(new, name)
            st_old = getattr(old, name)
            if st_new is None:
                if name == "vibration":
                    pass  # identity: signal unchanged
                continue
            if name == "hysteresis":
                if st_old is not None:
                    st_new.state = st_old.state.copy()
                    st_new._signs[:] = st_old._signs
                continue
            unchanged = same_order and st_old is not None and _same_linear_stage(name, st_old, st_new)
            if unchanged:
                _copy_linear_state(name, st_old, st_new)
                signal = taps.get(tap, signal) if tap in taps else signal
            elif signal is not None:
                signal = _settle(name, st_new, signal)

    def reset(self) -> None:
        """All states to rest; a finished pending configuration is applied without crossfade."""
        self._fade = None
        self._running = False
        self.poll()
        self.active.reset()
        self._last_in = None
        self._last_taps = None

    # -- streaming -----------------------------------------------------------------------------------------------
    def process(self, block: np.ndarray) -> np.ndarray:
        """One block ``Y_R [m] → U [V]`` (swaps first if a new configuration is ready)."""
        self.poll()
        x = np.ascontiguousarray(block, dtype=float)
        y, taps = self.active.process(x, taps=True)
        if self._fade is not None:
            old, done = self._fade
            y_old = old.process(x)
            M = self.crossfade_samples
            w = np.minimum((done + 1 + np.arange(x.shape[0])) / M, 1.0)[:, None]
            y = y_old + w * (y - y_old)
            done += x.shape[0]
            self._fade = None if done >= M else (old, done)
        if x.shape[0]:
            self._running = True
            self._last_in = x[-1].copy()
            self._last_taps = {k: v[-1].copy() for k, v in taps.items()} if self.active.cfg.cascade.order == "paper" \
                else None
        return y

    @property
    def crossfading(self) -> bool:
        return self._fade is not None

    def status(self) -> dict:
        return {"config_version": self.version, "pending_version": self.pending_version, "swaps": self.swaps,
                "failed_builds": self.failed_builds, "crossfading": self.crossfading, "last_error": self.last_error}


def _same_linear_stage(name, a, b) -> bool:
    if name == "vibration":
        return all(np.array_equal(x, y) for x, y in zip(a.continuous, b.continuous)) and a.dt == b.dt
    return a.cfg == b.cfg and a.dt == b.dt


def _copy_linear_state(name, src, dst) -> None:
    if name == "vibration":
        dst.filter.x[:] = src.filter.x
    else:
        dst.x[:] = src.x


def _settle(name, st, u) -> np.ndarray:
    """Put a linear stage at its steady state for the constant input ``u``; return its steady output."""
    if name == "vibration":
        ss = st.ss
        st.filter.settle_to(u)
        return _lin_steady_gain(ss.A, ss.B, ss.C, ss.D) @ u
    # creep compensator: yh = K⁻¹(yl − C x), x = (I − A)⁻¹ B yh  ⇒  yh = (K + C (I − A)⁻¹ B)⁻¹ yl
    ss = st.ss
    K = np.linalg.inv(st.Kinv)
    n = ss.n_states
    G = ss.C @ np.linalg.solve(np.eye(n) - ss.A, ss.B) if n else np.zeros_like(K)
    yh = np.linalg.solve(K + G, u)
    if n:
        st.x[:] = np.linalg.solve(np.eye(n) - ss.A, ss.B @ yh)
    return yh
