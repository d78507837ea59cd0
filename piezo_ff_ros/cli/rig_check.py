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
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterable, Sequence

import numpy as np

if TYPE_CHECKING:
    from ..core.config import PiezoConfig
    from ..core.hardware import DriverCore
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


def rig_check(cfg: PiezoConfig, backend_name: str, params: dict[str, Any], *, duration: float, block_size: int,
              write_ahead: float, test_voltage: float, ramp: SafeRampConfig, say: Callable[[str], None] = print,
              ) -> dict[str, Any]:
    """Run the checks (see the module docstring); return the report."""
    from ..core.hardware import DriverCore, DriverSettings
    from ..nodes.backends import get_spec

    fs = cfg.sample_rate
    lim = cfg.limits
    rep: dict[str, Any] = {"ok": False, "backend": backend_name, "sample_rate_hz": fs, "nominal_sample_rate_hz": fs,
           "latency_samples": None, "underruns": None, "safe_ramp_max_step_v": None, "checks": {}}
    checks: dict[str, dict[str, Any]] = rep["checks"]

    def check(name: str, ok: bool, **values: Any) -> bool:
        checks[name] = {"ok": bool(ok), **values}
        say(f"rig-check: {name:14s} {'ok ' if ok else 'FAIL'} " + ", ".join(f"{k}={v}" for k, v in values.items()))
        return ok

    # 1. link
    try:
        spec = get_spec(backend_name)
    except Exception as exc:  # noqa: BLE001 - unknown or broken plug-in: a failed link check, one line
        check("link", False, error=str(exc))
        return rep
    if backend_name == "sim":
        params = {"mode": "clocked", **params}
    try:
        bparams = spec.validate(params)
        backend = spec.create(cfg, bparams)
        settings = DriverSettings(sample_rate=fs, n_axes=cfg.n_axes, limits=lim, ramp=ramp, max_block=max(
            block_size, 20000), write_ahead=write_ahead, low_water=min(0.01, write_ahead / 2))
        core = DriverCore(settings, backend)
        run = _Run(core)
        run.take(core.start())
    except Exception as exc:  # noqa: BLE001 - the link check reports what failed, in one line
        check("link", False, error=str(exc))
        return rep
    info = backend.info
    check("link", True, device=info.name, axes=info.n_axes, clocked=info.clocked, sensor=info.has_sensor,
          fifo_depth=info.fifo_depth, params=bparams)
    try:
        # 2. sample clock (clocked devices): counter vs host clock over ~1 s of idle output
        if info.clocked:
            c0, t0 = backend.clock(), time.monotonic()
            run.wait(min(1.0, max(0.2, duration / 10)))
            c1, t1 = backend.clock(), time.monotonic()
            measured = (c1 - c0) / (t1 - t0)
            rep["sample_rate_hz"] = measured
            check("sample_clock", abs(measured / fs - 1) < 0.02, measured_hz=round(measured, 1), nominal_hz=fs)
        else:
            check("sample_clock", True, note="lockstep device: no clock of its own")
        # 4. paced stream at small voltages (the first block defines the stamp grid: stamp 0 = device index d0)
        underruns_before = core.status()["underrun_faults"]
        n_blocks = max(1, int(round(duration * fs / block_size)))
        k = np.arange(n_blocks * block_size)
        u_all = test_voltage * np.column_stack([np.sin(2 * np.pi * 5.0 * k / fs + i) for i in range(cfg.n_axes)])
        u_all *= np.minimum(1.0, k / (0.05 * fs))[:, None]      # fade in: no step at the start
        blocks = [(i * block_size * core.period_ns, u_all[i * block_size:(i + 1) * block_size])
                  for i in range(n_blocks)]
        say(f"rig-check: streaming {n_blocks} blocks of {block_size} samples "
            f"({n_blocks * block_size / fs:g} s) …")
        run.stream(blocks, pace=info.clocked)
        st = core.status()
        rep["underruns"] = st["underrun_faults"] - underruns_before     # while streaming
        lost = st["starved_samples"] + st["gap_samples"] + st["late_samples"]
        check("write_ahead", rep["underruns"] == 0 and lost == 0 and core.state != "fault",
              underruns=rep["underruns"], underruns_before_streaming=underruns_before,
              starved_samples=st["starved_samples"],
              late_samples=st["late_samples"], min_margin_samples=(None if math.isinf(run.min_margin)
                                                                   else int(run.min_margin)),
              block_size=block_size, write_ahead_samples=settings.samples(write_ahead))
        # 3. latency (the read delays were measured while streaming)
        rep["latency_samples"] = int(backend.latency_samples)
        measured_delay = None if math.isinf(run.read_delay) else int(run.read_delay)
        check("latency", info.has_sensor and (measured_delay is None or measured_delay >= 0),
              device_latency_samples=int(backend.latency_samples), measured_read_delay_samples=measured_delay,
              sensor=info.has_sensor)
        # 5.+6. a step request to the other side (slew limit), then no more input: after limits.stale_timeout the
        # driver ramps to the safe voltage (safe ramp); both read off the applied stream
        n_before = len(run.applied)
        u_from = core.guard.u_last.copy()
        step = np.tile(np.where(u_from > 0, -test_voltage, test_voltage), (block_size, 1))   # to the other side
        run.stream([(core.next_stamp, step)], pace=False)
        t_end = time.monotonic() + lim.stale_timeout + ramp.duration + 4 * write_ahead + 2.0
        while time.monotonic() < t_end:
            run.tick()
            if core.state == "safe" and run.applied and np.all(run.applied[-1][1][-1] == lim.safe_voltage):
                break
            time.sleep(0.002)
        u_app = np.vstack([u_from[None, :]] + [b for _, b in run.applied[n_before:]])
        at_target = np.flatnonzero(np.all(u_app == step[0], axis=1))
        reached = at_target.size > 0
        i_ramp = int(at_target[-1]) if reached else 0
        d = np.abs(np.diff(u_app[:i_ramp + 1], axis=0))
        max_step = float(d.max()) if d.size else 0.0
        allowed = lim.slew / fs
        check("slew_limit", max_step <= allowed * (1 + 1e-9) and reached, max_step_v=round(max_step, 6),
              allowed_v=allowed, limits_slew_v_per_s=lim.slew,
              requested_step_v=float(np.max(np.abs(step[0] - u_from))), target_reached=reached)
        r = np.abs(np.diff(u_app[i_ramp:], axis=0))
        moving = np.flatnonzero(np.any(r > 0, axis=1))
        ramp_step = float(r.max()) if r.size else 0.0
        ramp_len = int(moving[-1] - moving[0] + 1) if moving.size else 0
        rep["safe_ramp_max_step_v"] = ramp_step
        ramp_allowed = min(ramp.slew, lim.slew) / fs
        at_safe = bool(np.all(u_app[-1] == lim.safe_voltage))
        check("safe_ramp", core.state == "safe" and at_safe and 0 < ramp_step <= ramp_allowed * (1 + 1e-9) and
              ramp_len >= math.floor(ramp.duration * fs),
              max_step_v=round(ramp_step, 6), allowed_v=ramp_allowed, samples=ramp_len,
              min_samples=math.ceil(ramp.duration * fs), ends_at_safe=at_safe)
        st = core.status()
        rep["underruns_total"] = st["underrun_faults"]
        rep["faults"] = {k: st[f"{k}_faults"] for k in ("underrun", "overrun", "disconnect", "limit")}
    except Exception as exc:  # noqa: BLE001 - a device error mid-check: report it, never a traceback
        check("device", False, error=f"{type(exc).__name__}: {exc}")
    finally:
        try:
            core.close()
        except Exception as exc:  # noqa: BLE001
            check("close", False, error=str(exc))
    rep["ok"] = all(c["ok"] for c in checks.values())
    rep["errors"] = [t for lvl, t in run.log if lvl >= 2][:20]
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
