"""Soak benchmark of the node graph (a script, not a timed test).

The four nodes (driver with the sim plant, compensator with the full default cascade — H∞ vibration compensation
+ creep⁻¹ + hysteresis⁻¹ —, trajectory, recorder) run as separate processes over DDS, as piezo_ff_ros.ros.launcher
starts them, playing a circle for a long time while everything is recorded:

1. lockstep: ``--lockstep-seconds`` of signal (20 kHz samples) as fast as the graph answers;
2. realtime: ``--realtime-seconds`` of wall-clock play at 20 kHz (after ``--warmup`` s).

Figures per mode: signal and wall seconds; lost samples from the recording (every stamp exactly once, checked
with the independent ``mcap`` reader and with the package's ``read_run``) and from the driver's and compensator's
``/diagnostics`` counters; latency reference→displacement (realtime: receive times in this process; both modes:
the recorder's log times of the same stamp, in lockstep the round trip of a block through compensator + driver);
RSS of each node process sampled every ``--sample-period`` s (start, end, max, growth slope after the warm-up in
MB/h); CPU per node; recorded bytes; whether the MCAP reads end to end (package reader and ``mcap`` reader:
summary + every message); the replay analysis (tracking error, saturation); the machine's load average.

    PYTHONPATH=. nice -n 10 .venv/bin/python bench/soak.py [--lockstep-seconds 1800] [--realtime-seconds 600]
        [--block 200] [--out DIR] [--json F] [--skip-lockstep] [--skip-realtime] [--keep]

The MCAP files (≈ 0.8 MB per signal second at block 200) are deleted after the analysis unless ``--keep``.
"""
from __future__ import annotations

import argparse
import gc
import json
import math
import os
import resource
import struct
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _graph_common import claim_ros_domain, cpu_seconds, percentiles_ms, rss_bytes  # noqa: E402

from piezo_ff_ros.ros.env import apply_ros_env_defaults  # noqa: E402

_DOMAIN, _DOMAIN_LOCK = claim_ros_domain()  # held until this process exits (test sessions pick another)
apply_ros_env_defaults(domain_id=_DOMAIN, force_domain=True)

import numpy as np  # noqa: E402

FS = 20000.0
DT_NS = 50_000
BLOCK_TOPICS = ("/reference", "/voltage", "/displacement")
#: driver / compensator /diagnostics counters that say something was lost, late, rejected, clamped or faulted
LOSS_KEYS = ("blocks_in", "gaps", "gap_samples", "lost_blocks", "late_blocks", "late_samples",
             "out_of_sequence_blocks", "rebases", "starved_samples", "resumes", "rejected_blocks",
             "malformed_blocks", "clamped_samples", "slew_limited_samples", "device.underruns",
             "device.underrun_samples", "device.overruns", "device.overrun_samples", "workspace_clamped_samples",
             "applied_rejected", "blocks", "input_gaps", "input_gap_samples", "input_late_blocks",
             "input_workspace_clamped_samples", "stages", "hinf", "resync_active", "hysteresis_fallbacks",
             "failed_builds")


def loadavg() -> list[float]:
    return [round(v, 2) for v in os.getloadavg()]


def utc() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())


# -- the independent reader ------------------------------------------------------------------------------------------
def cdr_block_stamp(data: bytes) -> tuple[int, int]:
    """(stamp [ns], samples) of a sensor_msgs/PointCloud2 CDR message, parsed by hand (no package code)."""
    if data[1] != 1:
        raise ValueError("not little-endian CDR")
    sec, nsec = struct.unpack_from("<iI", data, 4)
    (n_frame,) = struct.unpack_from("<I", data, 12)
    off = 16 + n_frame                      # offsets count from the 4-byte encapsulation header
    off = 4 + (off - 4 + 3) // 4 * 4        # align 4 (height, width: uint32)
    height, width = struct.unpack_from("<II", data, off)
    return sec * 1_000_000_000 + nsec, height * width


def stamp_check(stamps: np.ndarray, sizes: np.ndarray) -> dict:
    """Every sample stamp exactly once? Blocks sorted by stamp: gaps, duplicates and overlaps, in samples."""
    order = np.argsort(stamps, kind="stable")
    s, n = stamps[order], sizes[order]
    if s.size == 0:
        return {"blocks": 0}
    ends = s + n * DT_NS
    step = s[1:] - ends[:-1]                # 0: contiguous; > 0: gap; < 0: overlap / duplicate
    return {"blocks": int(s.size), "samples": int(n.sum()), "first_stamp_ns": int(s[0]), "end_stamp_ns": int(ends[-1]),
            "span_samples": int((ends[-1] - s[0]) // DT_NS),
            "gap_samples": int(step[step > 0].sum() // DT_NS), "gaps": int((step > 0).sum()),
            "duplicate_blocks": int((s[1:] == s[:-1]).sum()), "overlap_samples": int(-step[step < 0].sum() // DT_NS),
            "off_grid": int(((s - s[0]) % DT_NS != 0).sum()), "block_sizes": sorted({int(v) for v in np.unique(n)})}


def mcap_check(path: Path) -> dict:
    """Read the file with the independent ``mcap`` library: summary, every message, per-topic stamp check,
    recorder-side latency (log time of the displacement minus that of the reference with the same stamp)."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    t0 = time.perf_counter()
    out: dict = {"ok": False}
    try:
        with open(path, "rb") as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            summary = reader.get_summary()
            if summary is None:
                raise ValueError("no summary section")
            stats = summary.statistics
            counts: dict[str, int] = {}
            stamps = {t: [] for t in BLOCK_TOPICS}
            logs = {t: [] for t in BLOCK_TOPICS}
            for _, channel, message in reader.iter_messages():
                counts[channel.topic] = counts.get(channel.topic, 0) + 1
                if channel.topic in stamps:
                    st, n = cdr_block_stamp(message.data)
                    stamps[channel.topic].append((st, n))
                    logs[channel.topic].append(message.log_time)
            # full decode of one message per channel through mcap_ros2 (schema text → message)
            dec = {}
            for _, channel, message, msg in reader.iter_decoded_messages(
                    topics=list(counts), log_time_order=False):
                if channel.topic not in dec:
                    dec[channel.topic] = type(msg).__name__
                    if len(dec) == len(counts):
                        break
        by_channel = {summary.channels[cid].topic: c for cid, c in stats.channel_message_counts.items()}
        out.update({
            "ok": all(counts.get(t, 0) == c for t, c in by_channel.items()) and sum(counts.values()) ==
            stats.message_count,
            "messages": sum(counts.values()), "summary_message_count": int(stats.message_count),
            "chunks": int(stats.chunk_count), "per_topic": counts, "decoded": dec,
            "stamps": {t: stamp_check(np.array([s for s, _ in v], np.int64), np.array([n for _, n in v], np.int64))
                       for t, v in stamps.items() if v}})
        ref = dict(zip((s for s, _ in stamps["/reference"]), logs["/reference"]))
        lat = [(lt - ref[s]) * 1e-9 for (s, _), lt in zip(stamps["/displacement"], logs["/displacement"]) if s in ref]
        out["recorder_latency_ms"] = percentiles_ms(lat)
    except Exception as exc:  # noqa: BLE001 - an unreadable file is a result, not a crash of the benchmark
        out["error"] = f"{type(exc).__name__}: {exc}"
    out["read_s"] = round(time.perf_counter() - t0, 2)
    return out


def package_check(path: Path) -> dict:
    """Read the file with the package's reader (``read_run``) and run the replay analysis on it."""
    from piezo_ff_ros.core.analysis import analyze_run
    from piezo_ff_ros.core.recording.mcap_io import read_run

    t0 = time.perf_counter()
    out: dict = {"ok": False}
    try:
        run = read_run(path)
        m = run.meta
        out.update({
            "ok": not m["truncated"] and not m["loss"]["chunks_lost"] and not m["loss"]["messages_lost"],
            "read_s": round(time.perf_counter() - t0, 2), "samples": int(len(run)),
            "signal_s": round(len(run) / FS, 3), "truncated": m["truncated"], "loss": {
                k: m["loss"][k] for k in ("chunks_total", "chunks_lost", "messages_lost", "bytes_skipped")},
            "blocks": {r: {k: b[k] for k in ("count", "missing_samples", "missing_blocks", "duplicates",
                                             "conflicts", "off_grid", "malformed", "outliers")}
                       for r, b in m["blocks"].items()},
            "lost_samples": {r: int(b["missing_samples"]) for r, b in m["blocks"].items()},
            "trimmed": m["trimmed"], "warnings": m["warnings"][:10],
            "u_max_abs_V": [round(float(v), 2) for v in np.nanmax(np.abs(run.u), axis=0)]})
        t1 = time.perf_counter()
        rep = analyze_run(run).to_json()["replay"]
        out["replay"] = {"tracking": _um(rep.get("tracking")), "saturation": rep.get("saturation"),
                         "analyze_s": round(time.perf_counter() - t1, 2)}
        del run, rep
    except Exception as exc:  # noqa: BLE001 - an unreadable file is a result
        out["error"] = f"{type(exc).__name__}: {exc}"
    gc.collect()
    return out


def package_check_subprocess(path: Path) -> dict:
    """:func:`package_check` in a child process, so that its peak RSS (``reader_peak_rss_MB``) is the reader's own."""
    import subprocess

    r = subprocess.run([sys.executable, __file__, "--read-only", str(path)], capture_output=True, text=True,
                       env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        return json.loads(r.stdout.strip().splitlines()[-1])
    except (ValueError, IndexError):
        return {"ok": False, "error": f"reader process exited {r.returncode}: {r.stderr.strip()[-500:]}"}


def _um(tracking):
    """Tracking figures [m] → µm for the printed report (keys get a ``_um`` suffix)."""
    if not tracking:
        return tracking
    out = {}
    for k, v in tracking.items():
        if isinstance(v, (list, tuple)) and all(isinstance(x, float) for x in v):
            out[f"{k}_um"] = [round(x * 1e6, 4) for x in v]
        elif isinstance(v, float) and k != "samples":
            out[f"{k}_um"] = round(v * 1e6, 4)
        else:
            out[k] = v
    return out


# -- process figures -------------------------------------------------------------------------------------------------
def rss_summary(samples: list[tuple[float, int]], warmup_s: float) -> dict:
    """start / end / max RSS [MB] and the growth slope [MB/h] fitted after the warm-up (least squares)."""
    t = np.array([s[0] for s in samples])
    mb = np.array([s[1] for s in samples]) / 1e6
    late = t >= t[0] + warmup_s
    slope = None
    if late.sum() >= 3 and np.ptp(t[late]) > 0:
        slope = round(float(np.polyfit(t[late] / 3600.0, mb[late], 1)[0]), 2)
    return {"start_MB": round(float(mb[0]), 1), "end_MB": round(float(mb[-1]), 1), "max_MB": round(float(mb.max()), 1),
            "after_warmup_MB": round(float(mb[late][0]), 1) if late.any() else None,
            "growth_MB_per_h": slope, "samples": int(len(samples))}


# -- one run ---------------------------------------------------------------------------------------------------------
def run_mode(mode: str, seconds: float, args, out: Path) -> dict:
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import PointCloud2
    from std_msgs.msg import String
    from std_srvs.srv import Trigger

    from piezo_ff_ros.nodes.common import LATCHED_QOS, RECORD_QOS, stamp_to_ns
    from piezo_ff_ros.ros.launcher import GraphLauncher

    play_s = seconds if mode == "lockstep" else seconds + args.warmup + 120.0  # realtime: stopped by us
    spec = {"type": "circle", "radius": args.radius, "frequency": args.frequency,
            "revolutions": round(play_s * args.frequency, 6)}
    mcap = out / f"soak_{mode}.mcap"
    if mcap.exists():
        mcap.unlink()
    traj = ["-p", f"mode:={mode}", "-p", f"block_size:={args.block}", "-p", "min_subscribers:=2",
            "-p", f"trajectory:='{json.dumps(spec)}'"]
    if mode == "lockstep":
        traj += ["-p", f"window:={args.window}"]
    res: dict = {"mode": mode, "block_size": args.block, "trajectory": spec, "started_utc": utc(),
                 "loadavg_start": loadavg()}
    driver = []
    if mode == "lockstep" and args.lockstep_stale_timeout:
        driver = ["-p", f"limits.stale_timeout:={float(args.lockstep_stale_timeout)}"]
        res["driver_stale_timeout_s"] = float(args.lockstep_stale_timeout)
    g = GraphLauncher({"recorder": ["-p", f"output:={mcap}"], "driver": driver, "compensator": [], "trajectory": traj},
                      log_dir=out / f"logs_{mode}", env=os.environ)
    t_launch = time.monotonic()
    g.start(timeout=600)
    res["startup_s"] = round(time.monotonic() - t_launch, 1)
    rclpy.init()
    node = rclpy.create_node(f"soak_{mode}")
    states: list[tuple[float, dict]] = []
    diags: dict[str, tuple[float, dict]] = {}
    node.create_subscription(String, "/trajectory/state",
                             lambda m: states.append((time.monotonic(), json.loads(m.data))), LATCHED_QOS)

    def on_diag(m):
        for st in m.status:
            diags[st.name] = (time.monotonic(), {kv.key: kv.value for kv in st.values}, int.from_bytes(st.level, "little")
                              if isinstance(st.level, bytes) else int(st.level), st.message)
    node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 50)
    t_ref: dict[int, float] = {}
    t_disp: dict[int, float] = {}
    probing = [False]
    if mode == "realtime":  # a probe of the two ends (in lockstep it would cost the graph a core: log times used)
        node.create_subscription(PointCloud2, "reference", lambda m: probing[0] and t_ref.setdefault(
            stamp_to_ns(m.header.stamp), time.monotonic()), RECORD_QOS)
        node.create_subscription(PointCloud2, "displacement", lambda m: probing[0] and t_disp.setdefault(
            stamp_to_ns(m.header.stamp), time.monotonic()), RECORD_QOS)
    cli = node.create_client(Trigger, "/trajectory/start")
    if not cli.wait_for_service(timeout_sec=60):
        raise RuntimeError("/trajectory/start not available")
    pids = {n: p.proc.pid for n, p in g.procs.items()}
    rss: dict[str, list] = {n: [] for n in pids}
    loads: list[list[float]] = []

    def sample(now):
        for n, pid in pids.items():
            try:
                rss[n].append((now, rss_bytes(pid)))
            except (OSError, ValueError):
                pass
        loads.append(loadavg())

    fut = cli.call_async(Trigger.Request())
    while not fut.done():
        rclpy.spin_once(node, timeout_sec=0.05)
    while not any(s["state"] in ("playing", "finished", "failed") for _, s in states):
        rclpy.spin_once(node, timeout_sec=0.05)
    t_play = next(t for t, s in states if s["state"] in ("playing", "finished", "failed"))
    cpu0 = {n: cpu_seconds(pid) for n, pid in pids.items()}
    w0 = time.monotonic()
    sample(w0)
    next_sample = w0 + args.sample_period
    next_print = w0 + 60.0
    error = None
    deadline = w0 + (args.lockstep_timeout if mode == "lockstep" else args.warmup + seconds)
    if mode == "realtime":
        probe_on = w0 + args.warmup
    while True:
        rclpy.spin_once(node, timeout_sec=0.02)
        now = time.monotonic()
        if mode == "realtime" and not probing[0] and now >= probe_on:
            probing[0] = True
            w_probe = now
        if now >= next_sample:
            sample(now)
            next_sample += args.sample_period
            try:
                g.check_alive()
            except RuntimeError as exc:
                error = str(exc)
                break
        if now >= next_print:
            next_print += 60.0
            drv = next((v for k, v in diags.items() if "driver" in k), None)
            print(f"  [{mode}] {now - w0:7.0f} s wall, driver blocks_in {drv[1].get('blocks_in') if drv else '?'}, "
                  f"load {loadavg()}", flush=True)
        if mode == "lockstep" and any(s["state"] in ("finished", "failed", "stopped") for _, s in states):
            break
        if now >= deadline:
            if mode == "lockstep":
                error = f"lockstep not finished after {args.lockstep_timeout} s wall: stopped"
                stop = node.create_client(Trigger, "/trajectory/stop")
                if stop.wait_for_service(timeout_sec=10):
                    f2 = stop.call_async(Trigger.Request())
                    t_stop = time.monotonic() + 10
                    while not f2.done() and time.monotonic() < t_stop:
                        rclpy.spin_once(node, timeout_sec=0.05)
            break
    w1 = time.monotonic()
    probing[0] = False
    cpu1 = {n: cpu_seconds(pid) for n, pid in pids.items() if g.procs[n].proc.poll() is None}
    sample(w1)
    # the driver's and compensator's counters after the last block: wait for a report from after the end
    t_wait = time.monotonic() + 8.0
    while time.monotonic() < t_wait and not all(
            any(n in k and v[0] > w1 + 0.5 for k, v in diags.items()) for n in ("driver", "compensator")):
        rclpy.spin_once(node, timeout_sec=0.05)
    end_state = next((s for _, s in reversed(states)), {})
    node.destroy_node()
    rclpy.try_shutdown()
    codes = g.stop(timeout=60)
    wall = w1 - w0
    res.update({
        "state": end_state.get("state"), "error": error or end_state.get("error"), "exit_codes": codes,
        "wall_s": round(wall, 2), "loadavg_end": loadavg(),
        "loadavg_1min_during": {"mean": round(float(np.mean([v[0] for v in loads])), 2),
                                "max": round(float(np.max([v[0] for v in loads])), 2)},
        "cpu_fraction_of_one_core": {n: round((cpu1[n] - cpu0[n]) / wall, 3) for n in cpu1},
        "rss": {n: rss_summary(v, args.rss_warmup) for n, v in rss.items() if v},
        "diagnostics": {k: {"level": v[2], "message": v[3], **{c: v[1][c] for c in LOSS_KEYS if c in v[1]}}
                        for k, v in diags.items()},
    })
    res["cpu_total"] = round(sum(res["cpu_fraction_of_one_core"].values()), 3)
    if mode == "realtime":
        res["probe"] = {"window_s": round(w1 - w_probe, 2), "reference_blocks": len(t_ref),
                        "displacement_blocks": len(t_disp),
                        "latency_ms": percentiles_ms(t_disp[s] - t_ref[s] for s in t_ref if s in t_disp)}
    res["recorded_bytes"] = mcap.stat().st_size if mcap.exists() else 0
    # analysis of the file
    res["mcap_reader"] = mcap_check(mcap)
    pkg = package_check_subprocess(mcap)
    res["package_reader"] = pkg
    sig = pkg.get("signal_s") or 0.0
    res["signal_s"] = sig
    res["real_time_factor"] = round(sig / wall, 2) if wall > 0 and mode == "lockstep" else None
    res["recorded_bytes_per_signal_s"] = round(res["recorded_bytes"] / sig) if sig else None
    drv = next((v for k, v in res["diagnostics"].items() if "driver" in k), {})
    res["lost_samples"] = {
        "recording_mcap": {t: st.get("gap_samples") for t, st in res["mcap_reader"].get("stamps", {}).items()},
        "recording_mcap_duplicate_blocks": {t: st.get("duplicate_blocks")
                                            for t, st in res["mcap_reader"].get("stamps", {}).items()},
        "recording_read_run": pkg.get("lost_samples"),
        "driver": {k: drv.get(k) for k in ("gap_samples", "late_samples", "starved_samples")}}
    res["finished_utc"] = utc()
    if not args.keep and mcap.exists():
        mcap.unlink()
        res["mcap_deleted"] = True
    return res


def brief(res: dict) -> str:
    """A few lines for the console."""
    r = res
    lines = [f"== {r['mode']}: {r['signal_s']} s of signal in {r['wall_s']} s wall (state {r['state']}, "
             f"error {r['error']}), load {r['loadavg_start']} → {r['loadavg_end']}",
             f"   lost samples: {json.dumps(r['lost_samples'])}",
             f"   latency: probe {r.get('probe', {}).get('latency_ms')}, recorder "
             f"{r['mcap_reader'].get('recorder_latency_ms')}",
             f"   cpu {r['cpu_fraction_of_one_core']} = {r['cpu_total']}",
             "   rss " + ", ".join(f"{n} {v['start_MB']}→{v['end_MB']} (max {v['max_MB']}, {v['growth_MB_per_h']} MB/h)"
                                   for n, v in r["rss"].items()),
             f"   recorded {r['recorded_bytes'] / 1e6:.1f} MB; mcap reader ok={r['mcap_reader']['ok']} "
             f"({r['mcap_reader'].get('messages')} msgs, {r['mcap_reader'].get('error')}), package reader "
             f"ok={r['package_reader']['ok']} ({r['package_reader'].get('error')}, peak RSS "
             f"{r['package_reader'].get('reader_peak_rss_MB')} MB)",
             f"   replay {json.dumps(r['package_reader'].get('replay'))}"]
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--lockstep-seconds", type=float, default=1800.0, help="signal seconds played in lockstep")
    ap.add_argument("--realtime-seconds", type=float, default=600.0, help="wall seconds measured in realtime")
    ap.add_argument("--block", type=int, default=200, help="samples per block")
    ap.add_argument("--window", type=int, default=4, help="lockstep blocks in flight")
    ap.add_argument("--radius", type=float, default=2e-5, help="circle radius [m]")
    ap.add_argument("--frequency", type=float, default=5.0, help="circle frequency [Hz]")
    ap.add_argument("--warmup", type=float, default=3.0, help="realtime: seconds before the latency probe starts")
    ap.add_argument("--rss-warmup", type=float, default=60.0, help="RSS samples before this [s] not in the slope")
    ap.add_argument("--sample-period", type=float, default=10.0, help="RSS/load sampling period [s]")
    ap.add_argument("--lockstep-timeout", type=float, default=5400.0, help="stop the lockstep run after this wall [s]")
    ap.add_argument("--lockstep-stale-timeout", type=float, default=None,
                    help="driver limits.stale_timeout [s] in the lockstep run (default: the config's, 0.2 s: a "
                         "longer stall of the loaded host then ramps the driver to safe and the run fails)")
    ap.add_argument("--out", default="/tmp/piezo_ff_soak")
    ap.add_argument("--json")
    ap.add_argument("--skip-lockstep", action="store_true")
    ap.add_argument("--skip-realtime", action="store_true")
    ap.add_argument("--keep", action="store_true", help="keep the MCAP files")
    ap.add_argument("--read-only", metavar="MCAP", help=argparse.SUPPRESS)  # internal: package_check in a child
    args = ap.parse_args(argv)
    if args.read_only:
        res = package_check(Path(args.read_only))
        res["reader_peak_rss_MB"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
        print(json.dumps(res, default=str))
        return 0
    for name in ("lockstep_seconds", "realtime_seconds", "sample_period", "lockstep_timeout"):
        v = getattr(args, name)
        if not (math.isfinite(v) and v > 0):
            ap.error(f"--{name.replace('_', '-')}: must be a positive number of seconds, got {v}")
    if not 1 <= args.block <= 20000:
        ap.error(f"--block: must be 1…20000 samples, got {args.block}")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        ap.error(f"--out: {out} exists and is not a directory")
    if args.json and (Path(args.json).is_dir() or not Path(args.json).resolve().parent.is_dir()):
        ap.error(f"--json: {args.json} is a directory or its directory does not exist")
    out.mkdir(parents=True, exist_ok=True)
    result = {"command": " ".join([Path(sys.executable).name, *sys.argv]), "date_utc": utc(),
              "loadavg_start": loadavg(), "cpus": os.cpu_count(), "nice": os.nice(0), "ros_domain": _DOMAIN}

    def save():
        if args.json:
            Path(args.json).write_text(json.dumps(result, indent=2, default=str) + "\n")

    for mode, skip, seconds in (("lockstep", args.skip_lockstep, args.lockstep_seconds),
                                ("realtime", args.skip_realtime, args.realtime_seconds)):
        if skip:
            continue
        print(f"{utc()} {mode}: {seconds} s, block {args.block}, load {loadavg()}", flush=True)
        try:
            result[mode] = run_mode(mode, seconds, args, out)
        except Exception as exc:  # noqa: BLE001 - keep the other mode's figures
            result[mode] = {"mode": mode, "error": f"{type(exc).__name__}: {exc}"}
            print(f"{mode} failed: {result[mode]['error']}", flush=True)
        else:
            print(brief(result[mode]), flush=True)
        result["loadavg_end"] = loadavg()
        save()
    return 0


if __name__ == "__main__":
    sys.exit(main())
