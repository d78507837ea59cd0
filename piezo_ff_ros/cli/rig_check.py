"""``piezo-ff rig-check --backend NAME [--param K=V …] [--json OUT] [--md OUT]``: what to run first on a new rig.

Runs the driver core (no ROS) against the backend and checks, in order:

1. **link** — the backend's parameters validate, the device opens and starts at the safe voltage;
2. **sample clock** — the device's sample counter against the host's clock (clocked devices);
3. **latency** — input→output latency in samples: the device's figure, and the delivery delay measured on reads
   (clock at the read − index after the newest sample delivered, the minimum over the run);
4. **write-ahead margin** — blocks of ``--block-size`` samples paced by the host clock for ``--duration`` s with a
   FIFO margin of ``--write-ahead`` s: underruns (device faults), starved samples (the driver had to hold), the
   smallest margin seen;
5. **slew limit** — a full-scale step request: the largest applied step must be ≤ ``limits.slew / fs``;
6. **safe ramp** — input stopped: the ramp to the safe voltage, its largest step (≤ ``safe_ramp.slew / fs``) and
   duration (≥ ``safe_ramp.duration``).

The test voltages stay within ``--test-voltage`` (default 10 % of the limit).  ``--backend sim`` runs the clocked
simulator (``--param mode=lockstep`` for the other one).  The report (JSON/Markdown) has at least ``ok``,
``sample_rate_hz``, ``latency_samples``, ``underruns`` (device underruns while streaming; ``underruns_total`` counts
the whole check), ``safe_ramp_max_step_v``; exit code 0 when ok, 1 otherwise.
"""
from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterable, NamedTuple, Sequence

import numpy as np

if TYPE_CHECKING:
    from ..core.config import PiezoConfig
    from ..core.hardware import DriverCore, DriverSettings, StreamingBackend
    from ..core.hardware.driver_core import Emit
    from ..core.safety import SafeRampConfig


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("rig-check", help="first checks on a rig: link, sample clock, latency, write-ahead, "
                                          "slew limit, safe ramp (Markdown/JSON report)")
    p.add_argument("--backend", default="sim", help="backend plug-in (sim, nidaqmx, pi_gcs, or an entry point)")
    p.add_argument("--param", action="append", default=[], metavar="K=V",
                   help="a backend parameter (repeatable), e.g. --param device=Dev1 (values parsed as YAML)")
    p.add_argument("--config", default=None, help="positioner config YAML (limits, axes, sample rate)")
    p.add_argument("--variant", default=None, help="config variant")
    p.add_argument("--duration", type=float, default=60.0, help="seconds of paced streaming (default 60)")
    p.add_argument("--block-size", type=int, default=200, help="samples per block (default 200 = 10 ms)")
    p.add_argument("--write-ahead", type=float, default=0.05, help="FIFO margin ahead of the clock [s]")
    p.add_argument("--test-voltage", type=float, default=None, help="largest test voltage [V] (default 10 %% "
                                                                     "of limits.voltage)")
    p.add_argument("--ramp-duration", type=float, default=0.05, help="safe ramp: minimum duration [s]")
    p.add_argument("--ramp-slew", type=float, default=1.0e4, help="safe ramp: maximum slew [V/s]")
    p.add_argument("--json", default=None, help="write the report as JSON")
    p.add_argument("--md", default=None, help="write the report as Markdown")
    p.set_defaults(func=run)


def _parse_params(items: Sequence[str]) -> dict[str, Any]:
    import yaml

    out: dict[str, Any] = {}
    for it in items:
        k, sep, v = it.partition("=")
        if not sep or not k.strip():
            raise ValueError(f"--param: expected K=V, got {it!r}")
        try:
            out[k.strip()] = yaml.safe_load(v)
        except yaml.YAMLError:
            out[k.strip()] = v
    return out


class _Run:
    """The driver core and what it emitted, with a host-paced loop."""

    def __init__(self, core: DriverCore) -> None:
        self.core = core
        self.applied: list = []
        self.measured: list = []
        self.log: list = []
        self.min_margin = math.inf
        self.read_delay = math.inf

    def take(self, em: Emit) -> Emit:
        self.applied += em.applied
        self.measured += em.displacement
        self.log += em.log
        return em

    def tick(self) -> Emit:
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


class _Link(NamedTuple):
    """An open device: the backend, the driver core started on it and the loop recording what it emits."""

    backend: StreamingBackend
    core: DriverCore
    run: _Run
    settings: DriverSettings


def _open_link(plan: _Plan, backend_name: str, params: dict[str, Any], report: _Report) -> _Link | None:
    """Check 1, link: find the backend, validate its parameters, open the device and start the driver.

    Parameters
    ----------
    plan : _Plan
        The options (sample rate, limits, block size, write-ahead, ramp).
    backend_name : str
        The backend plug-in.
    params : dict
        Its parameters (``sim`` defaults to ``mode=clocked``).
    report : _Report
        Receives the ``link`` check.

    Returns
    -------
    _Link or None
        None when the link check failed (the report says why).
    """
    from ..core.hardware import DriverCore, DriverSettings
    from ..backends import get_spec

    cfg, block_size, write_ahead = plan.cfg, plan.block_size, plan.write_ahead
    try:
        spec = get_spec(backend_name)
    except Exception as exc:  # noqa: BLE001 - unknown or broken plug-in: a failed link check, one line
        report.check("link", False, error=str(exc))
        return None
    if backend_name == "sim":
        params = {"mode": "clocked", **params}
    backend = None
    try:
        bparams = spec.validate(params)
        backend = spec.create(cfg, bparams)
        settings = DriverSettings(sample_rate=cfg.sample_rate, n_axes=cfg.n_axes, limits=cfg.limits, ramp=plan.ramp,
                                  max_block=max(block_size, 20000), write_ahead=write_ahead,
                                  low_water=min(0.01, write_ahead / 2))
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


def _test_blocks(plan: _Plan, period_ns: int) -> list[tuple[int, np.ndarray]]:
    """The paced test signal: 5 Hz sines at ``plan.test_voltage`` (one phase per axis), faded in over 50 ms.

    Parameters
    ----------
    plan : _Plan
        Duration, block size, test voltage.
    period_ns : int
        Sample period; the first block is stamp 0.

    Returns
    -------
    list of (stamp, block)
    """
    fs, block_size = plan.cfg.sample_rate, plan.block_size
    n_blocks = max(1, int(round(plan.duration * fs / block_size)))
    k = np.arange(n_blocks * block_size)
    u_all = plan.test_voltage * np.column_stack([np.sin(2 * np.pi * 5.0 * k / fs + i) for i in range(plan.cfg.n_axes)])
    u_all *= np.minimum(1.0, k / (0.05 * fs))[:, None]      # fade in: no step at the start
    return [(i * block_size * period_ns, u_all[i * block_size:(i + 1) * block_size]) for i in range(n_blocks)]


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
        self.latency()     # the read delays were measured while streaming
        # a step request to the other side (slew limit), then no more input: after limits.stale_timeout the driver
        # ramps to the safe voltage (safe ramp); both read off the applied stream
        rec = self.step_then_stop()
        self.safe_ramp(rec, self.slew_limit(rec))
        st = self.link.core.status()
        self.report.rep["underruns_total"] = st["underrun_faults"]
        self.report.rep["faults"] = {k: st[f"{k}_faults"] for k in ("underrun", "overrun", "disconnect", "limit")}

    def sample_clock(self) -> None:
        """Check 2: a clocked device's sample counter against the host clock over ``duration / 10`` (0.2 to 1 s)
        of idle output; sets ``sample_rate_hz`` to the measured rate."""
        backend, fs = self.link.backend, self.plan.cfg.sample_rate
        if backend.info.clocked:
            c0, t0 = backend.clock(), time.monotonic()
            self.link.run.wait(min(1.0, max(0.2, self.plan.duration / 10)))
            c1, t1 = backend.clock(), time.monotonic()
            measured = (c1 - c0) / (t1 - t0)
            self.report.rep["sample_rate_hz"] = measured
            self.report.check("sample_clock", abs(measured / fs - 1) < 0.02, measured_hz=round(measured, 1),
                              nominal_hz=fs)
        else:
            self.report.check("sample_clock", True, note="lockstep device: no clock of its own")

    def write_ahead(self) -> None:
        """Check 4: the test blocks streamed (paced by the host clock on a clocked device); underruns, lost samples
        and the smallest margin; sets ``underruns`` (those while streaming)."""
        core, run, plan = self.link.core, self.link.run, self.plan
        underruns_before = core.status()["underrun_faults"]
        # the first block defines the stamp grid: stamp 0 = device index d0
        blocks = _test_blocks(plan, core.period_ns)
        self.report.say(f"rig-check: streaming {len(blocks)} blocks of {plan.block_size} samples "
                        f"({len(blocks) * plan.block_size / plan.cfg.sample_rate:g} s) …")
        run.stream(blocks, pace=self.link.backend.info.clocked)
        st = core.status()
        underruns = self.report.rep["underruns"] = st["underrun_faults"] - underruns_before     # while streaming
        lost = st["starved_samples"] + st["gap_samples"] + st["late_samples"]
        self.report.check("write_ahead", underruns == 0 and lost == 0 and core.state != "fault",
                          underruns=underruns, underruns_before_streaming=underruns_before,
                          starved_samples=st["starved_samples"], late_samples=st["late_samples"],
                          min_margin_samples=None if math.isinf(run.min_margin) else int(run.min_margin),
                          block_size=plan.block_size, write_ahead_samples=self.link.settings.samples(plan.write_ahead))

    def latency(self) -> None:
        """Check 3: the device's latency figure (``latency_samples``) and the read delay measured while streaming."""
        backend, run = self.link.backend, self.link.run
        self.report.rep["latency_samples"] = int(backend.latency_samples)
        measured_delay = None if math.isinf(run.read_delay) else int(run.read_delay)
        self.report.check("latency", backend.info.has_sensor and (measured_delay is None or measured_delay >= 0),
                          device_latency_samples=int(backend.latency_samples),
                          measured_read_delay_samples=measured_delay, sensor=backend.info.has_sensor)

    def step_then_stop(self) -> _StepRecord:
        """A full step requested to the other side, then no input until the driver has ramped to the safe voltage
        (after ``limits.stale_timeout``), or the timeout, the ramp and a margin have passed."""
        core, run, plan, lim = self.link.core, self.link.run, self.plan, self.plan.cfg.limits
        n_before = len(run.applied)
        u_from = core.guard.u_last.copy()
        step = np.tile(np.where(u_from > 0, -plan.test_voltage, plan.test_voltage), (plan.block_size, 1))
        run.stream([(core.next_stamp, step)], pace=False)
        t_end = time.monotonic() + lim.stale_timeout + plan.ramp.duration + 4 * plan.write_ahead + 2.0
        while time.monotonic() < t_end:
            run.tick()
            if core.state == "safe" and run.applied and np.all(run.applied[-1][1][-1] == lim.safe_voltage):
                break
            time.sleep(0.002)
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
        d = np.abs(np.diff(u_app[:i_ramp + 1], axis=0))
        max_step = float(d.max()) if d.size else 0.0
        allowed = lim.slew / fs
        self.report.check("slew_limit", max_step <= allowed * (1 + 1e-9) and reached, max_step_v=round(max_step, 6),
                          allowed_v=allowed, limits_slew_v_per_s=lim.slew,
                          requested_step_v=float(np.max(np.abs(rec.step[0] - rec.u_from))), target_reached=reached)
        return i_ramp

    def safe_ramp(self, rec: _StepRecord, i_ramp: int) -> None:
        """Check 6: from row ``i_ramp`` on, steps of at most ``min(ramp.slew, limits.slew) / fs`` lasting at least
        ``ramp.duration``, ending at the safe voltage with the driver ``safe``; sets ``safe_ramp_max_step_v``."""
        lim, ramp, fs = self.plan.cfg.limits, self.plan.ramp, self.plan.cfg.sample_rate
        r = np.abs(np.diff(rec.u_app[i_ramp:], axis=0))
        moving = np.flatnonzero(np.any(r > 0, axis=1))
        ramp_step = float(r.max()) if r.size else 0.0
        ramp_len = int(moving[-1] - moving[0] + 1) if moving.size else 0
        self.report.rep["safe_ramp_max_step_v"] = ramp_step
        ramp_allowed = min(ramp.slew, lim.slew) / fs
        at_safe = bool(np.all(rec.u_app[-1] == lim.safe_voltage))
        self.report.check("safe_ramp", self.link.core.state == "safe" and at_safe
                          and 0 < ramp_step <= ramp_allowed * (1 + 1e-9) and ramp_len >= math.floor(ramp.duration * fs),
                          max_step_v=round(ramp_step, 6), allowed_v=ramp_allowed, samples=ramp_len,
                          min_samples=math.ceil(ramp.duration * fs), ends_at_safe=at_safe)


def rig_check(cfg: PiezoConfig, backend_name: str, params: dict[str, Any], *, duration: float, block_size: int,
              write_ahead: float, test_voltage: float, ramp: SafeRampConfig, say: Callable[[str], None] = print,
              ) -> dict[str, Any]:
    """Run the checks (see the module docstring); return the report."""
    plan = _Plan(cfg, duration, block_size, write_ahead, test_voltage, ramp)
    report = _Report(backend_name, cfg.sample_rate, say)
    link = _open_link(plan, backend_name, params, report)
    if link is None:
        return report.rep
    try:
        _Checks(link, plan, report).run_all()
    except Exception as exc:  # noqa: BLE001 - a device error mid-check: report it, never a traceback
        report.check("device", False, error=f"{type(exc).__name__}: {exc}")
    finally:
        try:
            link.core.close()
        except Exception as exc:  # noqa: BLE001
            report.check("close", False, error=str(exc))
    rep = report.rep
    rep["ok"] = all(c["ok"] for c in report.checks.values())
    rep["errors"] = [t for lvl, t in link.run.log if lvl >= 2][:20]
    return rep


def markdown(rep: dict) -> str:
    lines = [f"# rig-check: backend `{rep['backend']}` — {'OK' if rep['ok'] else 'FAILED'}", "",
             f"- sample rate: {rep['sample_rate_hz']:.1f} Hz (nominal {rep['nominal_sample_rate_hz']:g} Hz)",
             f"- latency: {rep['latency_samples']} samples", f"- underruns: {rep['underruns']}",
             f"- safe ramp largest step: {rep['safe_ramp_max_step_v']} V", "", "| check | ok | values |",
             "| --- | --- | --- |"]
    for name, c in rep["checks"].items():
        vals = ", ".join(f"{k}={v}" for k, v in c.items() if k != "ok")
        lines.append(f"| {name} | {'yes' if c['ok'] else '**no**'} | {vals} |")
    return "\n".join(lines) + "\n"


def run(args: argparse.Namespace) -> int:
    from ..core.config import load_config
    from ..core.safety import SafeRampConfig

    cfg = load_config(args.config, variant=args.variant)
    for name in ("duration", "write_ahead", "ramp_duration", "ramp_slew"):
        v = getattr(args, name)
        if not (math.isfinite(v) and v >= 0):
            raise ValueError(f"--{name.replace('_', '-')}: must be a finite number ≥ 0, got {v}")
    if not 1 <= args.block_size <= 10 * cfg.sample_rate:
        raise ValueError(f"--block-size: must be in [1, {int(10 * cfg.sample_rate)}], got {args.block_size}")
    tv = 0.1 * cfg.limits.voltage if args.test_voltage is None else args.test_voltage
    if not (math.isfinite(tv) and 0 < tv <= cfg.limits.voltage):
        raise ValueError(f"--test-voltage: must be in (0, {cfg.limits.voltage}] V, got {tv}")
    for out in (args.json, args.md):
        if out and (Path(out).is_dir() or not Path(out).resolve().parent.is_dir()):
            raise ValueError(f"{out}: not a writable file path")
    ramp = SafeRampConfig(duration=args.ramp_duration, slew=args.ramp_slew).validate()
    cfg = replace(cfg, limits=cfg.limits.validate())
    rep = rig_check(cfg, args.backend, _parse_params(args.param), duration=args.duration,
                    block_size=args.block_size, write_ahead=args.write_ahead, test_voltage=tv, ramp=ramp)
    if args.json:
        Path(args.json).write_text(json.dumps(rep, indent=2, default=str))
    if args.md:
        Path(args.md).write_text(markdown(rep))
    print(f"rig-check: {'OK' if rep['ok'] else 'FAILED'}")
    return 0 if rep["ok"] else 1
