"""Python launcher for the node graph (``ros2 launch`` is not available from pip; see launch/piezo_ff.launch.py).

Starts driver, compensator, trajectory, plotter and recorder as subprocesses (``python -m piezo_ff_ros.nodes.<name>``) with
the safe ROS environment (:func:`piezo_ff_ros.ros.env.apply_ros_env_defaults`: localhost discovery, own domain,
logs in a temp dir), waits until each node has logged that it is ready, and stops them with SIGINT (trajectory
first, recorder last, so that the recording holds everything).  No ROS import in :class:`GraphLauncher`; the
command (:func:`main`) starts the trajectory once the recorder and every block writer have matched
(:class:`~piezo_ff_ros.ros.graph_session.GraphClient`), so that ``run.mcap`` holds the first blocks.

Command line::

    python -m piezo_ff_ros.ros.launcher [--out DIR] [--mode realtime|lockstep] [--duration S] [--trajectory SPEC]
                                        [--params-file FILE] [--plot-rate HZ]

The managed driver is started unconfigured and stepped to active (configure, activate) once every node is ready.
"""
from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Mapping, Sequence

from .env import apply_ros_env_defaults

NODES = ("driver", "compensator", "trajectory", "plotter", "recorder")
READY_MARKERS = {"driver": "driver ready", "compensator": "compensator ready", "trajectory": "trajectory ready",
                 "plotter": "plotter ready", "recorder": "recording "}
STOP_ORDER = ("trajectory", "compensator", "driver", "plotter", "recorder")
#: managed (lifecycle) nodes: started unconfigured (``autostart:=false`` unless the caller sets it), then stepped
#: through these transitions once every node is ready — what a launch file or a supervisor does
MANAGED = {"driver": ("configure", "activate")}


class NodeProcess:
    """One node subprocess with its log file."""

    def __init__(self, name: str, args: list[str], env: Mapping[str, str], log_dir: Path) -> None:
        self.name = name
        self.log_path = log_dir / f"{name}.log"
        self._log = open(self.log_path, "wb")
        repo = str(Path(__file__).resolve().parents[2])   # the directory holding the piezo_ff_ros package
        env = dict(env)
        env["PYTHONPATH"] = repo + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
        env.setdefault("PYTHONUNBUFFERED", "1")
        self.proc = subprocess.Popen([sys.executable, "-m", f"piezo_ff_ros.nodes.{name}", "--ros-args", *args],
                                     env=env, stdout=self._log, stderr=subprocess.STDOUT)

    def log(self) -> str:
        """The node's output so far (empty if unreadable)."""
        try:
            return self.log_path.read_text(errors="replace")
        except OSError:
            return ""

    @property
    def ready(self) -> bool:
        """The node has logged its ready marker."""
        return READY_MARKERS.get(self.name, "ready") in self.log()

    def stop(self, timeout: float = 10.0) -> int:
        """SIGINT, then terminate/kill if it does not exit within ``timeout`` s; returns the exit code."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.terminate()
                try:
                    self.proc.wait(3)
                except subprocess.TimeoutExpired:
                    self.proc.kill()
                    self.proc.wait()
        self._log.close()
        return self.proc.returncode


class GraphLauncher:
    """Start/stop the node graph.

    Parameters
    ----------
    node_args : dict
        ``{node: [ros args after --ros-args]}``, e.g. ``{"trajectory": ["-p", "mode:=lockstep"]}``; nodes not
        listed are not started.
    log_dir : path, optional
        Where each node's output goes (``<node>.log``); default a temp dir.
    domain_id : int, optional
        ROS_DOMAIN_ID for the graph (default: the caller's, else derived from the PID).
    """

    def __init__(self, node_args: Mapping[str, Sequence[str]], log_dir: str | Path | None = None,
                 domain_id: int | None = None, env: Mapping[str, str] | None = None) -> None:
        self.env = apply_ros_env_defaults(domain_id=domain_id, env=dict(os.environ if env is None else env),
                                          force_domain=domain_id is not None)
        self.node_args = {n: list(a) for n, a in node_args.items()}
        self.log_dir = Path(log_dir) if log_dir else Path(tempfile.mkdtemp(prefix="piezo_ff_graph_"))
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self.procs: dict[str, NodeProcess] = {}

    def start(self, timeout: float = 90.0) -> None:
        """Start every node and wait until all logged ready; RuntimeError (with the node's log tail) otherwise."""
        for name in NODES:
            if name in self.node_args:
                args = self.node_args[name]
                if name in MANAGED and not any(str(a).startswith("autostart:=") for a in args):
                    args = ["-p", "autostart:=false", *args]
                self.procs[name] = NodeProcess(name, args, self.env, self.log_dir)
        deadline = time.monotonic() + timeout
        pending = set(self.procs)
        while pending:
            for name in list(pending):
                p = self.procs[name]
                if p.ready:
                    pending.discard(name)
                elif p.proc.poll() is not None:
                    self.stop()
                    raise RuntimeError(f"node {name} exited with code {p.proc.returncode}:\n{_tail(p.log())}")
            if time.monotonic() > deadline:
                self.stop()
                raise RuntimeError(f"nodes not ready after {timeout} s: {sorted(pending)}")
            time.sleep(0.1)
        self._step_managed(max(deadline - time.monotonic(), 10.0))

    def _step_managed(self, timeout: float) -> None:
        """Configure and activate the managed nodes started unconfigured (RuntimeError with the log tail)."""
        for name, transitions in MANAGED.items():
            p = self.procs.get(name)
            if p is None or "ready: unconfigured" not in p.log():
                continue   # not started here, or started with autostart
            from .graph_session import step_lifecycle

            try:
                step_lifecycle(f"/{name}", transitions, domain_id=int(self.env["ROS_DOMAIN_ID"]), timeout=timeout)
            except RuntimeError as exc:
                self.stop()
                raise RuntimeError(f"{exc}:\n{_tail(p.log())}") from None

    def check_alive(self) -> None:
        """RuntimeError (with the node's log tail) if a started node has exited."""
        for name, p in self.procs.items():
            if p.proc.poll() is not None:
                raise RuntimeError(f"node {name} exited with code {p.proc.returncode}:\n{_tail(p.log())}")

    def stop(self, timeout: float = 15.0) -> dict[str, int]:
        """SIGINT in :data:`STOP_ORDER`; returns ``{node: exit code}``."""
        codes: dict[str, int] = {}
        for name in STOP_ORDER:
            if name in self.procs:
                codes[name] = self.procs[name].stop(timeout)
        return codes

    def __enter__(self) -> GraphLauncher:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def _tail(text: str, n: int = 15) -> str:
    return "\n".join(text.strip().splitlines()[-n:])


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m piezo_ff_ros.ros.launcher``: start the graph, run until ``--duration`` or Ctrl-C, stop it."""
    ap = argparse.ArgumentParser(prog="python -m piezo_ff_ros.ros.launcher", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=".", help="directory for run.mcap and the node logs")
    ap.add_argument("--mode", choices=("realtime", "lockstep"), default="realtime")
    ap.add_argument("--duration", type=float, default=0.0, help="stop after this many seconds (0: on Ctrl-C)")
    ap.add_argument("--trajectory", default="", help="trajectory spec (JSON/YAML), default: the node's circle")
    ap.add_argument("--params-file", default="", help="compensator params file")
    ap.add_argument("--plot-rate", type=float, default=200.0,
                    help="rate of the plotter's plot_* topics [Hz] (Foxglove/PlotJuggler; recorded too)")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    # started by this launcher once every block writer has matched the recorder (see below), not on its own
    traj = ["-p", f"mode:={args.mode}", "-p", "autostart:=false", "-p", "min_subscribers:=2"]  # + the recorder
    if args.trajectory:
        traj += ["-p", f"trajectory:='{args.trajectory}'"]  # quoted: a YAML string, not a mapping
    comp = ["--params-file", args.params_file] if args.params_file else []
    g = GraphLauncher({"recorder": ["-p", f"output:={out / 'run.mcap'}"], "driver": [], "compensator": comp,
                       "trajectory": traj, "plotter": ["-p", f"rate:={args.plot_rate}"]}, log_dir=out / "logs")
    g.start()
    print(f"graph running (ROS_DOMAIN_ID={g.env['ROS_DOMAIN_ID']}), logs in {g.log_dir}; Ctrl-C to stop")
    client = None
    end: dict[str, Any] | None = None
    try:
        from .graph_session import GraphClient

        # the trajectory plays once the recorder and every block writer have matched: a writer sends nothing to a
        # reader it has not matched yet, and the first blocks would be missing from run.mcap
        client = GraphClient("piezo_ff_launcher", domain_id=int(g.env["ROS_DOMAIN_ID"]))
        client.wait_recorder_connected(check=g.check_alive)
        n_before = len(client.states)
        client.trigger(client.start)
        t_end = time.monotonic() + args.duration if args.duration > 0 else float("inf")
        while time.monotonic() < t_end and end is None:   # a finite trajectory ends the run when it has played
            g.check_alive()
            client.spin_for(0.2)
            end = next((st for st in client.states[n_before:] if st["state"] in ("finished", "failed", "stopped")),
                       None)
    except KeyboardInterrupt:
        pass
    finally:
        if client is not None:
            client.close()
        codes = g.stop()
    played = f"trajectory {end['state']}{': ' + end['error'] if end.get('error') else ''}; " if end else ""
    print(f"stopped: {codes}; {played}recording {out / 'run.mcap'}")
    return 0 if all(c == 0 for c in codes.values()) and (end is None or end["state"] == "finished") else 1


if __name__ == "__main__":
    sys.exit(main())
