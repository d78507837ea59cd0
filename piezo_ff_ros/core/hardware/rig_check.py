"""The rig-check engine (no ROS, no command line): what to run first on a new rig, against any
:class:`~.contract.StreamingBackend` through the :class:`~.driver_core.DriverCore`.

Checks, in order (``piezo-ff rig-check`` is the command; :func:`rig_check` the function):

1. **link** — the backend opens and starts at the safe voltage;
2. **sample clock** — the device's sample counter against the host's clock (skipped on a device without a hardware
   clock);
3. **write-ahead margin** — blocks paced by the host clock for ``duration`` s with a FIFO margin of ``write_ahead``
   s: underruns (device faults, through the driver's fault → safe-ramp path), starved and late samples, the smallest
   margin seen (skipped without a FIFO ahead of a clock);
4. **latency** — the command→sensor latency **measured**: a white excitation (±``test_voltage``/2), the applied
   voltage and the sensor on the same stamps, their cross-correlation per axis; the latency is the first lag at
   which the correlation is significant (``≥ max(0.1·peak, 5/√n)``): the *residual* delay, beyond what the
   backend's sensor tags already account for (its ``latency_samples``); on a positioner it includes the stage's
   own response time.  With ``loopback`` (the sensor inputs wired to the command outputs, the NI way of
   measuring AO→AI latency) the residual must be 0 and ``latency_samples`` in the report is the value to give the
   driver (``<backend>.latency_samples``); without, the residual must be causal (≥ 0; a sensor tagged before its
   command means ``latency_samples`` is too large) and the sensor must follow the command (peak ≥ 0.2).  Skipped
   without a sensor stream;
5. **slew limit** — a step request: the largest applied step must be ≤ ``limits.slew / fs``;
6. **safe ramp** — input stopped: the ramp to the safe voltage, its largest step (≤ ``safe_ramp.slew / fs``) and
   duration (≥ ``safe_ramp.duration``);
7. **faults** — no device fault (any of the contract's ``FAULT_KINDS``) during the whole check.

On a set-and-hold device (``info.holds_setpoints``: a PI controller in set-point mode) the output moves as a paced
staircase, so checks 5 and 6 judge each change of the applied stream against the samples elapsed since the previous
change: ``|Δv| ≤ min(step · elapsed samples, max(SETPOINT_STEP_MAX, step))`` (the safety invariant of
docs/hardware.md: set points no more than 1 V apart, paced); their ``max_step_v`` is then the largest change per
elapsed sample period, ``setpoint_max_step_v`` the largest change between two changes.  The applied stream has one
value per sample, so a sample's own step larger than 1 V (allowed only when ``step`` is) is split into set points
the record cannot show: the backend's tests check those on the controller's wire.  The ramp's duration counts its
first stair as long as the others.

Every check is ``{"ok": true|false|null, ...}``; a check that does not apply is ``ok: null`` with ``skipped``
(the reason).  The report has at least ``ok``, ``sample_rate_hz``, ``latency_samples``, ``underruns`` (device
underruns while streaming; ``underruns_total`` counts the whole check), ``safe_ramp_max_step_v``.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Iterator, NamedTuple

import numpy as np

from ..config import PiezoConfig
from ..safety import SafeRampConfig
from .contract import FAULT_KINDS, StreamingBackend
from .driver_core import DriverCore, DriverSettings, DriverOutput

__all__ = ["rig_check", "markdown", "DEFAULT_WRITE_AHEAD"]

#: the write-ahead rig-check uses unless told otherwise: the driver's default (``DriverSettings.write_ahead``)
DEFAULT_WRITE_AHEAD = DriverSettings.write_ahead
#: a set-and-hold device: the largest change between two consecutive set points [V] (unless one sample's step is
#: larger: the backend then splits it within the sample)
SETPOINT_STEP_MAX = 1.0


def _judge_steps(u: np.ndarray, step: float, holds: bool, judge_from: int = 0) -> dict[str, Any]:
    """The largest change in the applied stream ``u [N, axes]`` (row 0: the value before) against ``step`` V per
    sample: per sample for a device that outputs each sample; per elapsed sample period between consecutive
    changes for a set-and-hold device.  Returns ``{"ok", "max_step_v", ...}`` (``max_step_v`` per sample period,
    comparable with ``step``; for a set-and-hold device also ``setpoint_max_step_v``, ``setpoints`` and
    ``stair_samples``, the median number of samples between changes).  Only the changes after row ``judge_from``
    are judged; the rows before count for the time a set point was held."""
    d = np.abs(np.diff(u, axis=0)).max(axis=1) if u.shape[0] > 1 and u.shape[1] else np.zeros(0)
    if not holds:
        worst = float(d[judge_from:].max()) if d[judge_from:].size else 0.0
        return {"ok": worst <= step * (1 + 1e-9), "max_step_v": worst}
    rows = np.flatnonzero(d > 0)
    elapsed_all = np.diff(np.concatenate([[-1], rows])).astype(float)   # samples since the previous change
    keep = rows >= judge_from
    rows = rows[keep]
    if not rows.size:
        return {"ok": True, "max_step_v": 0.0, "setpoint_max_step_v": 0.0, "setpoints": 0, "stair_samples": 0,
                "judged": "per elapsed time between set points"}
    elapsed = elapsed_all[keep]
    change = d[rows]
    allowed = np.minimum(step * elapsed, max(SETPOINT_STEP_MAX, step))
    ok = bool(np.all(change <= allowed * (1 + 1e-9) + 1e-12))
    return {"ok": ok, "max_step_v": float(np.max(change / elapsed)), "setpoint_max_step_v": float(change.max()),
            "setpoints": int(rows.size), "stair_samples": int(np.median(elapsed[1:])) if rows.size > 1 else 1,
            "setpoint_step_allowed_v": max(SETPOINT_STEP_MAX, step),
            "judged": "per elapsed time between set points"}


class _Run:
    """The driver core and what it emitted, with a host-paced loop."""

    def __init__(self, core: DriverCore) -> None:
        self.core = core
        self.applied: list[tuple[int, np.ndarray]] = []
        self.measured: list[tuple[int, np.ndarray]] = []
        self.log: list[tuple[int, str]] = []
        self.min_margin = math.inf
        self.read_delay = math.inf

    def take(self, em: DriverOutput) -> DriverOutput:
        self.applied += em.applied
        self.measured += em.displacement
        self.log += em.log
        return em

    def tick(self) -> DriverOutput:
        em = self.take(self.core.tick())
        if self.core.info.clocked and self.core.state != "fault":
            clock = self.core.backend.clock()
            self.min_margin = min(self.min_margin, self.core.status().get("write_ahead_samples", math.inf))
            if em.displacement:
                s, b = em.displacement[-1]
                k_end = self.core.book.device_index(s) + b.shape[0]
                self.read_delay = min(self.read_delay, clock - k_end)
        return em

    def stream(self, blocks: Iterable[tuple[Any, np.ndarray]], pace: bool) -> None:
        """Send blocks ``[(stamp, u)]``, paced by the host clock when ``pace`` (one block per block duration)."""
        fs = self.core.s.sample_rate
        t_next = time.monotonic()
        for stamp, u in blocks:
            if pace:
                while time.monotonic() < t_next:
                    self.tick()
                    time.sleep(min(0.002, max(0.0, t_next - time.monotonic())))
                t_next += u.shape[0] / fs
            self.take(self.core.on_block(stamp, u))
            if not self.core.info.clocked:
                self.tick()

    def wait(self, seconds: float) -> None:
        """Keep ticking for ``seconds`` of host time."""
        t_end = time.monotonic() + seconds
        while time.monotonic() < t_end:
            self.tick()
            time.sleep(0.002)


@dataclass(frozen=True)
class _Plan:
    """What the checks are asked to do (the options of :func:`rig_check`)."""

    cfg: PiezoConfig
    duration: float               #: paced streaming [s]
    block_size: int               #: samples per block
    write_ahead: float            #: FIFO margin ahead of the clock [s]
    test_voltage: float           #: largest test voltage [V]
    ramp: SafeRampConfig          #: the safe ramp the driver is set up with
    loopback: bool = False        #: the sensor inputs are wired to the command outputs (latency must be exact)


class _Report:
    """The report being filled in; every check is printed as it is recorded."""

    def __init__(self, backend_name: str, fs: float, say: Callable[[str], None]) -> None:
        self.rep: dict[str, Any] = {"ok": False, "backend": backend_name, "sample_rate_hz": fs,
                                    "nominal_sample_rate_hz": fs, "latency_samples": None, "underruns": None,
                                    "safe_ramp_max_step_v": None, "checks": {}}
        self.checks: dict[str, dict[str, Any]] = self.rep["checks"]
        self.say = say

    def check(self, name: str, ok: bool, **values: Any) -> bool:
        """Record and print one check.

        Parameters
        ----------
        name : str
            The check (a key of ``rep['checks']``).
        ok : bool
            Whether it passed.
        **values
            What it measured (stored with ``ok``).

        Returns
        -------
        bool
            ``ok``.
        """
        self.checks[name] = {"ok": bool(ok), **values}
        self.say(f"rig-check: {name:14s} {'ok ' if ok else 'FAIL'} " + ", ".join(f"{k}={v}" for k, v in values.items()))
        return ok

    def skip(self, name: str, reason: str, **values: Any) -> None:
        """Record and print a check that does not apply to this device (``ok`` null, ``skipped`` the reason)."""
        self.checks[name] = {"ok": None, "skipped": reason, **values}
        self.say(f"rig-check: {name:14s} skipped ({reason})")


class _Link(NamedTuple):
    """An open device: the backend, the driver core started on it and the loop recording what it emits."""

    backend: StreamingBackend
    core: DriverCore
    run: _Run
    settings: DriverSettings


#: ``open_backend() -> (backend, validated parameters)``; raises with a one-line message when it cannot
OpenBackend = Callable[[], "tuple[StreamingBackend, dict[str, Any]]"]


def _open_link(plan: _Plan, open_backend: OpenBackend, report: _Report) -> _Link | None:
    """Check 1, link: open the device (``open_backend``) and start the driver core on it.

    Returns None when the link check failed (the report says why); a device that opened but did not start is
    closed.
    """
    cfg, block_size, write_ahead = plan.cfg, plan.block_size, plan.write_ahead
    backend = None
    try:
        backend, bparams = open_backend()
        settings = DriverSettings(sample_rate=cfg.sample_rate, n_axes=cfg.n_axes, limits=cfg.limits, ramp=plan.ramp,
                                  max_block=max(block_size, 20000), write_ahead=write_ahead,
                                  low_water=min(DriverSettings.low_water, write_ahead / 2))
        core = DriverCore(settings, backend)
        run = _Run(core)
        run.take(core.start())
    except Exception as exc:  # noqa: BLE001 - the link check reports what failed, in one line
        report.check("link", False, error=str(exc))
        if backend is not None:   # opened but not started: do not leave the device (task, connection) held
            try:
                backend.close()
            except Exception as close_exc:  # noqa: BLE001 - the link error is the one to report
                report.checks["link"]["close_error"] = str(close_exc)
        return None
    info = backend.info
    report.check("link", True, device=info.name, axes=info.n_axes, clocked=info.clocked, sensor=info.has_sensor,
                 fifo_depth=info.fifo_depth, params=bparams)
    return _Link(backend, core, run, settings)


def _test_blocks(plan: _Plan, period_ns: int) -> Iterator[tuple[int, np.ndarray]]:
    """The paced test signal, made block by block as it is sent (building a minute of it at once takes longer than
    the write-ahead on a loaded host, while nothing feeds the device): 5 Hz sines at ``plan.test_voltage`` (one
    phase per axis), faded in over 50 ms; the first block is stamp 0."""
    fs, block_size = plan.cfg.sample_rate, plan.block_size
    phase = np.arange(plan.cfg.n_axes)
    for i in range(_n_test_blocks(plan)):
        k = np.arange(i * block_size, (i + 1) * block_size)[:, None]
        u = plan.test_voltage * np.sin(2 * np.pi * 5.0 * k / fs + phase) * np.minimum(1.0, k / (0.05 * fs))
        yield i * block_size * period_ns, u


def _n_test_blocks(plan: _Plan) -> int:
    return max(1, int(round(plan.duration * plan.cfg.sample_rate / plan.block_size)))


class _StepRecord(NamedTuple):
    """A step request to the other side and the applied stream from before it to the end of the safe ramp."""

    u_from: np.ndarray            #: applied voltage before the step, per axis
    step: np.ndarray              #: the requested block (every row the target)
    u_app: np.ndarray             #: ``u_from``, then every sample applied since


@dataclass(frozen=True)
class _Checks:
    """Checks 2 to 6 on an open device (``link``) with the options of ``plan``, each recorded in ``report``."""

    link: _Link
    plan: _Plan
    report: _Report

    def run_all(self) -> None:
        """Every check in order, then the fault totals of the whole check (device errors propagate)."""
        self.sample_clock()
        self.write_ahead()
        self.latency()
        # a step request to the other side (slew limit), then no more input: after limits.stale_timeout the driver
        # ramps to the safe voltage (safe ramp); both read off the applied stream
        rec = self.step_then_stop()
        self.safe_ramp(rec, self.slew_limit(rec))
        st = self.link.core.status()
        self.report.rep["underruns_total"] = st["underrun_faults"]
        faults = self.report.rep["faults"] = {k: st.get(f"{k}_faults", 0) for k in FAULT_KINDS}
        self.report.check("faults", not any(faults.values()), **faults)

    def sample_clock(self) -> None:
        """Check 2: a clocked device's sample counter against the host clock over ``duration / 10`` (0.2 to 1 s)
        of idle output; sets ``sample_rate_hz`` to the measured rate."""
        backend, fs = self.link.backend, self.plan.cfg.sample_rate
        if not backend.info.clocked:
            self.report.skip("sample_clock", "no hardware sample clock: the device outputs each sample when it is "
                                             "written")
            return
        # (host time, device count) pairs read back to back while idling; the rate is their least-squares slope,
        # from the pairs whose read was not interrupted (a loaded host may deschedule us between the two reads)
        pairs = []
        t_end = time.monotonic() + min(1.0, max(0.2, self.plan.duration / 10))
        while time.monotonic() < t_end:
            self.link.run.tick()
            ta = time.monotonic()
            c = backend.clock()
            tb = time.monotonic()
            pairs.append((tb - ta, 0.5 * (ta + tb), c))
            time.sleep(0.002)
        pa = np.array(pairs)
        good = pa[pa[:, 0] <= max(2e-4, float(np.quantile(pa[:, 0], 0.5)))]
        measured = float(np.polyfit(good[:, 1] - good[0, 1], good[:, 2] - good[0, 2], 1)[0]) if len(good) > 2 \
            else float((pa[-1, 2] - pa[0, 2]) / (pa[-1, 1] - pa[0, 1]))
        self.report.rep["sample_rate_hz"] = measured
        self.report.check("sample_clock", abs(measured / fs - 1) < 0.02, measured_hz=round(measured, 1),
                          nominal_hz=fs)

    def write_ahead(self) -> None:
        """Check 3: the test blocks streamed, paced by the host clock; underruns (device faults, handled by the
        driver's fault path), lost samples and the smallest margin; sets ``underruns`` (those while streaming)."""
        core, run, plan = self.link.core, self.link.run, self.plan
        underruns_before = core.status()["underrun_faults"]
        blocks = _test_blocks(plan, core.period_ns)
        clocked = self.link.backend.info.clocked
        n_blocks = _n_test_blocks(plan)
        self.report.say(f"rig-check: streaming {n_blocks} blocks of {plan.block_size} samples "
                        f"({n_blocks * plan.block_size / plan.cfg.sample_rate:g} s) …")
        run.stream(blocks, pace=clocked)
        st = core.status()
        underruns = self.report.rep["underruns"] = st["underrun_faults"] - underruns_before     # while streaming
        if not clocked:
            self.report.skip("write_ahead", "no FIFO ahead of a hardware clock: nothing can run dry",
                             underruns=underruns, late_samples=st["late_samples"])
            return
        lost = st["starved_samples"] + st["gap_samples"] + st["late_samples"]
        ok = underruns == 0 and underruns_before == 0 and lost == 0 and core.state != "fault"
        values: dict[str, Any] = dict(
            underruns=underruns, underruns_before_streaming=underruns_before, starved_samples=st["starved_samples"],
            late_samples=st["late_samples"], min_margin_samples=None if math.isinf(run.min_margin)
            else int(run.min_margin), block_size=plan.block_size,
            write_ahead_samples=self.link.settings.samples(plan.write_ahead))
        if not ok:
            values["remedy"] = (f"raise the write-ahead (driver parameter write_ahead, rig-check --write-ahead; "
                                f"now {plan.write_ahead:g} s) or unload the host")
        self.report.check("write_ahead", ok, **values)

    def latency(self) -> None:
        """Check 4: the command→sensor latency from a white excitation and the cross-correlation of the applied
        voltage with the sensor on the same stamps (see the module docstring)."""
        backend, core, run, plan = self.link.backend, self.link.core, self.link.run, self.plan
        configured = int(backend.latency_samples)
        self.report.rep["latency_samples"] = configured
        if not backend.info.has_sensor:
            self.report.skip("latency", "no sensor stream: nothing answers the command",
                             device_latency_samples=configured)
            return
        fs, n_axes = plan.cfg.sample_rate, plan.cfg.n_axes
        n = int(round(0.25 * fs)) // plan.block_size * plan.block_size or plan.block_size
        rng = np.random.default_rng(12345)
        u = core.safe + 0.5 * plan.test_voltage * rng.uniform(-1.0, 1.0, size=(n, n_axes))
        s0 = core.next_stamp
        assert s0 is not None      # the stream has started (the write-ahead check streamed)
        blocks = [(s0 + i * core.period_ns, u[i:i + plan.block_size]) for i in range(0, n, plan.block_size)]
        n_applied, n_measured = len(run.applied), len(run.measured)
        run.stream(blocks, pace=backend.info.clocked)
        lag_max = max(20, int(0.01 * fs))
        t_end = time.monotonic() + 2.0 + (configured + lag_max) / fs
        applied, measured = self._on_grid(s0, n, run.applied[n_applied:]), None
        while time.monotonic() < t_end:
            measured = self._on_grid(s0, n, run.measured[n_measured:])
            applied = self._on_grid(s0, n, run.applied[n_applied:])
            if np.all(np.isfinite(measured)) and np.all(np.isfinite(applied)):
                break
            run.tick()
            if backend.info.clocked:
                time.sleep(0.002)
        measured = self._on_grid(s0, n, run.measured[n_measured:]) if measured is None else measured
        both = np.all(np.isfinite(applied), axis=1) & np.all(np.isfinite(measured), axis=1)
        lo, hi = _longest_run(both)
        if hi - lo < n // 2:
            self.report.check("latency", False, error=f"only {hi - lo} of {n} excitation samples came back in one "
                                                      "piece with both voltage and sensor (samples lost?)",
                              device_latency_samples=configured)
            return
        k = np.arange(lo, hi)
        axes = []
        for ax in range(n_axes):
            axes.append(_xcorr_latency(applied[k, ax], measured[k, ax], lag_max))
        residual = max(a["onset_lag_samples"] for a in axes)
        peak = min(a["peak"] for a in axes)
        measured_latency = configured + residual
        values: dict[str, Any] = dict(device_latency_samples=configured, residual_samples=residual,
                                      loopback=plan.loopback,
                                      read_delay_samples=None if math.isinf(run.read_delay) else int(run.read_delay),
                                      axes={plan.cfg.axes[i]: a for i, a in enumerate(axes)})
        if plan.loopback:
            values["measured_latency_samples"] = measured_latency
        if plan.loopback:
            ok = residual == 0 and peak >= 0.5
            self.report.rep["latency_samples"] = measured_latency
            if residual != 0:
                values["remedy"] = f"set the backend's latency_samples to {measured_latency} (--param " \
                                   f"latency_samples={measured_latency}; the driver node: <backend>.latency_samples)"
        else:
            ok = residual >= 0 and peak >= 0.2
            if residual < 0:
                values["remedy"] = (f"the sensor answers {-residual} sample(s) before its command: the backend's "
                                    f"latency_samples ({configured}) is too large")
        if peak < (0.5 if plan.loopback else 0.2):
            values["remedy"] = "the sensor does not follow the command (wiring, sensor channels, sensor gain?)"
        self.report.check("latency", ok, **values)
        self._settle()

    def _settle(self) -> None:
        """Tick until the driver, left without input, has ramped to the safe voltage and the device has output it
        (bounded): the next check starts from rest, not from the excitation still in the FIFO."""
        self._until_ramped_and_output()

    def _until_ramped_and_output(self) -> None:
        """Tick (no input) until the driver has ramped to the safe voltage after ``limits.stale_timeout`` **and**
        the device has output the ramp's last sample (the write-ahead may be longer than the stale timeout), or
        the timeout, the ramp, the write-ahead and a margin have passed."""
        core, run, plan, lim = self.link.core, self.link.run, self.plan, self.plan.cfg.limits
        t_end = time.monotonic() + lim.stale_timeout + plan.ramp.duration + 4 * plan.write_ahead + 2.0
        ramp_end = None
        while time.monotonic() < t_end and core.state != "fault":
            run.tick()
            if core.state == "safe" and ramp_end is None:
                ramp_end = core._w      # the ramp's end (the driver's holds may follow it)
            if ramp_end is not None and run.applied:
                s, b = run.applied[-1]
                d = core.book.device_index(s)
                if d is not None and d + b.shape[0] >= ramp_end and np.all(b[-1] == lim.safe_voltage):
                    break
            if core.info.clocked:
                time.sleep(0.002)

    def _on_grid(self, s0: int, n: int, blocks: list[tuple[int, np.ndarray]]) -> np.ndarray:
        """Samples of ``blocks`` ``(stamp, [m, axes])`` on the grid ``s0 + i·period``, i < n (NaN where absent)."""
        out = np.full((n, self.plan.cfg.n_axes), np.nan)
        period = self.link.core.period_ns
        for stamp, b in blocks:
            i0 = (stamp - s0) // period
            lo, hi = max(0, i0), min(n, i0 + b.shape[0])
            if hi > lo:
                out[lo:hi] = b[lo - i0:hi - i0]
        return out

    def step_then_stop(self) -> _StepRecord:
        """A full step requested to the other side, then no input until the driver has ramped to the safe voltage
        (after ``limits.stale_timeout``), or the timeout, the ramp and a margin have passed."""
        core, run, plan, lim = self.link.core, self.link.run, self.plan, self.plan.cfg.limits
        n_before = len(run.applied)
        u_from = core.guard.u_last.copy()
        step = np.tile(np.where(u_from > 0, -plan.test_voltage, plan.test_voltage), (plan.block_size, 1))
        run.stream([(core.next_stamp, step)], pace=False)
        self._until_ramped_and_output()
        u_app = np.vstack([u_from[None, :]] + [b for _, b in run.applied[n_before:]])
        return _StepRecord(u_from, step, u_app)

    def slew_limit(self, rec: _StepRecord) -> int:
        """Check 5: the step reached its target in steps of at most ``limits.slew / fs``.

        Returns the row of ``rec.u_app`` where the safe ramp starts (the last at the target; 0 if never reached).
        """
        lim, fs, u_app = self.plan.cfg.limits, self.plan.cfg.sample_rate, rec.u_app
        at_target = np.flatnonzero(np.all(u_app == rec.step[0], axis=1))
        reached = at_target.size > 0
        i_ramp = int(at_target[-1]) if reached else 0
        allowed = lim.slew / fs
        j = _judge_steps(u_app[:i_ramp + 1], allowed, self.link.backend.info.holds_setpoints)
        ok = j.pop("ok")
        self.report.check("slew_limit", ok and reached, max_step_v=round(j.pop("max_step_v"), 6),
                          allowed_v=allowed, limits_slew_v_per_s=lim.slew,
                          requested_step_v=float(np.max(np.abs(rec.step[0] - rec.u_from))), target_reached=reached,
                          **j)
        return i_ramp

    def safe_ramp(self, rec: _StepRecord, i_ramp: int) -> None:
        """Check 6: from row ``i_ramp`` on, steps of at most ``min(ramp.slew, limits.slew) / fs`` lasting at least
        ``ramp.duration``, ending at the safe voltage with the driver ``safe``; sets ``safe_ramp_max_step_v``."""
        lim, ramp, fs = self.plan.cfg.limits, self.plan.ramp, self.plan.cfg.sample_rate
        holds = self.link.backend.info.holds_setpoints
        seg = rec.u_app[i_ramp:]
        r = np.abs(np.diff(seg, axis=0))
        moving = np.flatnonzero(np.any(r > 0, axis=1))
        ramp_allowed = min(ramp.slew, lim.slew) / fs
        # judged from the ramp's start; the hold at the target before it counts for the first stair's time
        j = _judge_steps(rec.u_app, ramp_allowed, holds, judge_from=i_ramp)
        steps_ok, ramp_step = j.pop("ok"), j.pop("max_step_v")
        ramp_len = int(moving[-1] - moving[0] + 1) if moving.size else 0
        if holds and moving.size:
            # a staircase's first set point ends the ramp's first stair: count that stair as long as the others
            ramp_len += max(0, int(j["stair_samples"]) - 1)
        self.report.rep["safe_ramp_max_step_v"] = ramp_step
        at_safe = bool(np.all(rec.u_app[-1] == lim.safe_voltage))
        self.report.check("safe_ramp", self.link.core.state == "safe" and at_safe
                          and steps_ok and ramp_step > 0 and ramp_len >= math.floor(ramp.duration * fs),
                          max_step_v=round(ramp_step, 6), allowed_v=ramp_allowed, samples=ramp_len,
                          min_samples=math.ceil(ramp.duration * fs), ends_at_safe=at_safe, **j)


def _longest_run(mask: np.ndarray) -> tuple[int, int]:
    """``(start, stop)`` of the longest run of True in ``mask`` ((0, 0) if none)."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    if not starts.size:
        return 0, 0
    i = int(np.argmax(stops - starts))
    return int(starts[i]), int(stops[i])


def _xcorr_latency(u: np.ndarray, y: np.ndarray, lag_max: int) -> dict[str, Any]:
    """Normalised cross-correlation of command ``u`` and sensor ``y`` for lags −lag_max … lag_max (y later than u
    by the lag): the peak, its lag and the onset (first lag whose magnitude reaches ``max(0.1·peak, 5/√n)``)."""
    u = u - u.mean()
    y = y - y.mean()
    n = u.size
    norm = math.sqrt(float(np.dot(u, u)) * float(np.dot(y, y))) or 1.0
    lags = list(range(-lag_max, lag_max + 1))
    c = np.array([np.dot(u[max(0, -lag):n - max(0, lag)], y[max(0, lag):n - max(0, -lag)]) for lag in lags]) / norm
    a = np.abs(c)
    i_peak = int(np.argmax(a))
    threshold = max(0.1 * a[i_peak], 5.0 / math.sqrt(n))
    onset = int(lags[int(np.flatnonzero(a >= threshold)[0])])
    return {"onset_lag_samples": onset, "peak_lag_samples": int(lags[i_peak]), "peak": round(float(a[i_peak]), 4)}


def rig_check(cfg: PiezoConfig, backend_name: str, open_backend: OpenBackend, *, duration: float, block_size: int,
              write_ahead: float = DEFAULT_WRITE_AHEAD, test_voltage: float, ramp: SafeRampConfig,
              loopback: bool = False, say: Callable[[str], None] = print) -> dict[str, Any]:
    """Run the checks (see the module docstring) on the device ``open_backend()`` opens; return the report.

    A device error never ends the check with a traceback: faults go through the driver's fault path and are
    reported by the checks they spoil; anything else is a failed ``device`` check.  The device is closed (by the
    driver core: a ramp to the safe voltage first) whatever happened.
    """
    plan = _Plan(cfg, duration, block_size, write_ahead, test_voltage, ramp, loopback)
    report = _Report(backend_name, cfg.sample_rate, say)
    link = _open_link(plan, open_backend, report)
    if link is None:
        return report.rep
    try:
        _Checks(link, plan, report).run_all()
    except Exception as exc:  # noqa: BLE001 - a device error mid-check: report it, never a traceback
        report.check("device", False, error=f"{type(exc).__name__}: {exc}")
    finally:
        try:
            link.run.take(link.core.close())
        except Exception as exc:  # noqa: BLE001
            report.check("close", False, error=str(exc))
    rep = report.rep
    rep["ok"] = all(c["ok"] is not False for c in report.checks.values())
    rep["errors"] = [t for lvl, t in link.run.log if lvl >= 2][:20]
    return rep


def markdown(rep: dict[str, Any]) -> str:
    """The report as Markdown (a summary, then one table row per check)."""
    lines = [f"# rig-check: backend `{rep['backend']}` — {'OK' if rep['ok'] else 'FAILED'}", "",
             f"- sample rate: {rep['sample_rate_hz']:.1f} Hz (nominal {rep['nominal_sample_rate_hz']:g} Hz)",
             f"- latency: {rep['latency_samples']} samples", f"- underruns: {rep['underruns']}",
             f"- safe ramp largest step: {rep['safe_ramp_max_step_v']} V", "", "| check | ok | values |",
             "| --- | --- | --- |"]
    for name, c in rep["checks"].items():
        vals = ", ".join(f"{k}={v}" for k, v in c.items() if k not in ("ok", "skipped"))
        status = "skipped: " + str(c["skipped"]) if c["ok"] is None else "yes" if c["ok"] else "**no**"
        lines.append(f"| {name} | {status} | {vals} |")
    return "\n".join(lines) + "\n"


