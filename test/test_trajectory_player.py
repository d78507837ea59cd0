"""The trajectory player (core/trajectory_player.py), without ROS: a fake clock and a fake graph that answers each
reference block after a latency (or never), so the lockstep window, the acknowledgement expiry, the timeouts and
the realtime pacing are checked to the sample and to the tick."""
from __future__ import annotations

import heapq
import math
import threading
import time

import numpy as np
import pytest

from piezo_ff_ros.core.config import ConfigError
from piezo_ff_ros.core.status import ERROR, WARN
from piezo_ff_ros.core.trajectories import from_dict
from piezo_ff_ros.core.trajectory_player import PlaySettings, TrajectoryPlayer, check_play_params, parse_trajectory

FS = 20000.0
PERIOD_NS = 50_000
WALL0 = 1_700_000_000_123_456_789   # the wall clock [ns] when the fake monotonic clock reads T0
T0 = 100.0


class FakeGraph:
    """A fake clock, and a graph that answers block ``i`` ``latency`` seconds after it is sent unless ``i`` is in
    ``drop``; answers arrive while the player waits (as a condition variable's notify would wake it)."""

    def __init__(self, latency: float = 0.002, drop: set[int] | None = None, answer_n: int = 0):
        self.t = T0
        self.latency = latency
        self.drop = drop or set()
        self.answer_n = answer_n          # answer with this many samples instead of the block's (0: the block's)
        self.pending: list[tuple[float, int, int]] = []
        self.sent: list[tuple[float, int, np.ndarray]] = []
        self.markers: list[dict] = []
        self.states: list[dict] = []
        self.logs: list[tuple[int, str]] = []
        self.graph_waits: list[tuple[float, bool]] = []
        self.max_in_flight = 0
        self.player: TrajectoryPlayer | None = None
        self.on_send = None

    # -- PlayerHost ----------------------------------------------------------------------------------------------
    def monotonic(self) -> float:
        return self.t

    def wall_ns(self) -> int:
        return WALL0 + int(round((self.t - T0) * 1e9))

    def sleep(self, seconds: float) -> None:
        self._advance(self.t + seconds)

    def wait(self, cv, seconds: float) -> None:
        target = self.t + seconds
        if self.pending and self.pending[0][0] < target:
            target = self.pending[0][0]
        self._advance(target)

    def wait_graph(self, timeout: float, lockstep: bool) -> None:
        self.graph_waits.append((timeout, lockstep))

    def publish_reference(self, block, axes, stamp_ns):
        i = len(self.sent)
        self.sent.append((self.t, stamp_ns, block.copy()))
        self.max_in_flight = max(self.max_in_flight, self.player.in_flight)
        if i not in self.drop:
            heapq.heappush(self.pending, (self.t + self.latency, stamp_ns, self.answer_n or len(block)))
        if self.on_send is not None:
            self.on_send(i)

    def publish_experiment(self, info):
        self.markers.append(dict(info))

    def publish_state(self, state):
        self.states.append(dict(state))

    def log(self, level, text):
        self.logs.append((level, text))

    # -- the fake time -------------------------------------------------------------------------------------------
    def _advance(self, t: float) -> None:
        self.t = max(self.t, t)
        while self.pending and self.pending[0][0] <= self.t:
            _, stamp, n = heapq.heappop(self.pending)
            self.player.on_ack(stamp, n)


def _player(graph: FakeGraph, t0_ns: int = 0) -> TrajectoryPlayer:
    p = TrajectoryPlayer(graph, PERIOD_NS, t0_ns)
    graph.player = p
    return p


def _circle(seconds: float = 0.05):
    return from_dict({"type": "circle", "radius": 1e-5, "frequency": 20.0, "revolutions": seconds * 20.0})


def _stamps(graph: FakeGraph) -> np.ndarray:
    return np.array([s for _, s, _ in graph.sent], np.int64)


def test_lockstep_plays_every_sample_once_never_more_than_window_in_flight():
    g = FakeGraph()
    p = _player(g, t0_ns=1_000_000_007)
    traj = _circle(0.05)                                      # 1000 samples: 6 blocks of 170, the last of 150
    p.play(traj, FS, PlaySettings(mode="lockstep", block_size=170, window=3))
    assert p.t0_ns == 1_000_000_007 // PERIOD_NS * PERIOD_NS   # on the sample grid
    assert g.graph_waits == [(10.0, True)]
    assert [len(b) for _, _, b in g.sent] == [170] * 5 + [150]
    np.testing.assert_array_equal(_stamps(g), p.t0_ns + PERIOD_NS * np.arange(0, 1000, 170))
    np.testing.assert_array_equal(np.vstack([b for _, _, b in g.sent]), traj.block(0, 1000, FS))
    assert g.max_in_flight == 3                 # counted as each block goes out, itself included
    assert p.in_flight == 0 and p.k_stream == 1000
    assert g.states[0]["state"] == "playing" and g.states[0]["total"] == 1000 and g.states[0]["start"] == 0
    assert g.states[-1] == {"state": "finished", "mode": "lockstep", "k": 1000, "unanswered_blocks": 0, "blocks": 6}
    # the next run continues the stream: its samples never reuse an index
    g.max_in_flight = 0
    p.play(traj, FS, PlaySettings(mode="lockstep", block_size=500, window=1))
    np.testing.assert_array_equal(_stamps(g)[6:], p.t0_ns + PERIOD_NS * np.array([1000, 1500]))
    assert g.max_in_flight == 1


def test_lockstep_window_is_what_gates_the_next_block():
    """With a slow graph (answers after 10 ms), block i + window is sent when block i's answer came back."""
    g = FakeGraph(latency=0.010)
    p = _player(g)
    p.play(_circle(0.05), FS, PlaySettings(mode="lockstep", block_size=100, window=4))
    times = np.array([t for t, _, _ in g.sent]) - T0
    np.testing.assert_allclose(times, np.repeat([0.0, 0.010, 0.020], 4)[:10], atol=1e-12)
    assert g.states[-1]["state"] == "finished"


def test_an_answer_for_a_later_block_gives_up_the_earlier_ones_at_once():
    g = FakeGraph(drop={2})
    p = _player(g)
    p.play(_circle(0.05), FS, PlaySettings(mode="lockstep", block_size=100, window=4, ack_timeout=5.0))
    assert g.states[-1]["state"] == "finished" and g.states[-1]["unanswered_blocks"] == 1
    assert g.t - T0 < 0.1                                        # no wait for the ack timeout
    warns = [t for lv, t in g.logs if lv == WARN]
    assert warns == ["lockstep: 1 block(s) never answered (the driver answered a later block), given up: 1 so far"]
    assert any(s.get("unanswered_blocks") == 1 and s["state"] == "playing" for s in g.states)


def test_an_unanswered_last_block_is_given_up_after_ack_timeout_and_the_run_finishes():
    g = FakeGraph(drop={9})
    p = _player(g)
    p.play(_circle(0.05), FS, PlaySettings(mode="lockstep", block_size=100, window=4, ack_timeout=0.5,
                                           lockstep_timeout=3.0))
    assert g.states[-1]["state"] == "finished" and g.states[-1]["unanswered_blocks"] == 1
    # given up at the first poll after 0.5 s without an answer (polls every 0.1 s of the fake clock)
    assert 0.5 < g.t - g.sent[9][0] <= 0.5 + 0.1 + 1e-9
    assert "no displacement within ack_timeout 0.5 s" in g.logs[-2][1]


def test_no_answer_at_all_fails_the_run_after_lockstep_timeout():
    g = FakeGraph(drop=set(range(100)))
    p = _player(g)
    p.play(_circle(0.05), FS, PlaySettings(mode="lockstep", block_size=100, window=4, ack_timeout=5.0,
                                           lockstep_timeout=2.0))
    end = g.states[-1]
    assert end["state"] == "failed" and end["blocks"] == 4
    assert end["error"] == "lockstep: no displacement for 2.0 s (is the driver running?)"
    assert 2.0 < g.t - T0 <= 2.1 + 1e-9
    assert (ERROR, end["error"]) in g.logs and p.in_flight == 0


def test_a_run_whose_last_blocks_never_come_back_fails_naming_how_many():
    g = FakeGraph(drop={8, 9})
    p = _player(g)
    p.play(_circle(0.05), FS, PlaySettings(mode="lockstep", block_size=100, window=4, ack_timeout=5.0,
                                           lockstep_timeout=1.0))
    assert g.states[-1]["state"] == "failed"
    assert g.states[-1]["error"] == "lockstep: 2 block(s) never answered"


def test_samples_the_driver_published_itself_are_never_reused():
    """An answer longer than the block (the driver's own safe-state ramp) moves the stream index past it: the next
    run starts after it."""
    g = FakeGraph(answer_n=150)
    p = _player(g, t0_ns=WALL0)
    p.play(_circle(0.01), FS, PlaySettings(mode="lockstep", block_size=100, window=1))   # 200 samples
    np.testing.assert_array_equal((_stamps(g) - p.t0_ns) // PERIOD_NS, [0, 100])
    assert p.k_stream == 250                       # the second block's answer covered samples 100 … 249
    p.on_ack(p.t0_ns - 10 * PERIOD_NS, 5)          # a block from before t0 (another run): nothing moves
    assert p.k_stream == 250
    p.play(_circle(0.01), FS, PlaySettings(mode="lockstep", block_size=200, window=1))
    assert (_stamps(g)[-1] - p.t0_ns) // PERIOD_NS == 250


def test_realtime_is_paced_by_the_clock_and_stamped_by_the_wall_clock():
    g = FakeGraph()
    p = _player(g, t0_ns=WALL0 - 777 * PERIOD_NS - 123)
    g.t = T0 + 0.25                                  # started 0.25 s after the player was built
    p.play(_circle(0.05), FS, PlaySettings(mode="realtime", block_size=200))
    times = np.array([t for t, _, _ in g.sent]) - (T0 + 0.25)
    np.testing.assert_allclose(times, np.arange(5) * 200 / FS, atol=1e-9)   # one block every 10 ms
    k0 = (g.wall_ns() - int(round(0.04 * 1e9)) - p.t0_ns) // PERIOD_NS     # the wall clock at the start
    np.testing.assert_array_equal((_stamps(g) - p.t0_ns) // PERIOD_NS, k0 + np.arange(0, 1000, 200))
    assert g.graph_waits == [(10.0, False)] and g.states[-1]["state"] == "finished"


def test_segments_are_announced_before_their_first_block_with_their_own_end():
    spec = {"type": "sequence", "segments": [
        {"name": "hold", "trajectory": {"type": "hold", "value": 0.0, "duration": 0.004}, "meta": {"stages": ["x"]}},
        {"name": "circle", "trajectory": {"type": "circle", "radius": 1e-6, "frequency": 100.0, "revolutions": 1},
         "meta": {"note": 3}}]}
    traj = from_dict(spec)
    g = FakeGraph()
    p = _player(g, t0_ns=WALL0)
    p.on_ack(p.t0_ns + 40 * PERIOD_NS, 10)                      # the stream is at sample 50
    p.play(traj, FS, PlaySettings(mode="lockstep", block_size=64, window=2))
    assert g.markers == [
        {"name": "hold", "k0": 50, "stamp_ns": p.t0_ns + 50 * PERIOD_NS, "stages": ["x"], "k1": 130},
        {"name": "circle", "k0": 130, "stamp_ns": p.t0_ns + 130 * PERIOD_NS, "stages": None, "note": 3, "k1": 330}]
    # the hold's marker precedes the first block, the circle's the block holding sample 130 (50 + 64 … 50 + 127)
    assert len(g.sent) == math.ceil(280 / 64)


def test_preview_plays_the_trajectory_ahead():
    g = FakeGraph()
    p = _player(g)
    traj = _circle(0.05)
    p.play(traj, FS, PlaySettings(mode="lockstep", block_size=250, window=2, preview_s=0.001))
    np.testing.assert_array_equal(np.vstack([b for _, _, b in g.sent]), traj.block(20, 1000, FS))


def test_a_loop_plays_again_until_stopped():
    g = FakeGraph()
    p = _player(g)
    g.on_send = lambda i: p.stop(join=False) if i == 24 else None
    p.play(_circle(0.05), FS, PlaySettings(mode="lockstep", block_size=100, window=4, loop=True))
    assert len(g.sent) == 25 and p.stopping
    assert [s["start"] for s in g.states if s["state"] == "playing"] == [0, 1000, 2000]
    assert g.states[-1]["state"] == "stopped" and g.states[-1]["blocks"] == 25


def test_a_graph_that_never_gets_ready_fails_the_run():
    g = FakeGraph()

    def never(timeout, lockstep):
        raise TimeoutError(f"graph not ready after {timeout} s")
    g.wait_graph = never
    p = _player(g)
    p.play(_circle(0.05), FS, PlaySettings(mode="lockstep", lockstep_timeout=0.5))
    assert g.states[-1]["state"] == "failed" and g.states[-1]["error"] == "graph not ready after 0.5 s"
    assert not g.sent


def test_start_plays_in_a_thread_and_refuses_a_second_start():
    g = FakeGraph()
    gate = threading.Event()
    g.wait_graph = lambda timeout, lockstep: gate.wait(30)
    p = _player(g)
    ok, msg = p.start(_circle(0.05), FS, PlaySettings(mode="lockstep", block_size=100, window=4))
    assert ok and msg == "playing Circle from sample 0" and p.playing
    assert p.start(_circle(0.05), FS, PlaySettings()) == (False, "already playing (call ~/stop first)")
    gate.set()
    deadline = time.monotonic() + 30
    while p.playing and time.monotonic() < deadline:
        time.sleep(0.001)
    assert not p.playing and g.states[-1]["state"] == "finished" and len(g.sent) == 10


def test_stop_ends_a_run_waiting_for_the_graph():
    g = FakeGraph()
    gate = threading.Event()
    g.wait_graph = lambda timeout, lockstep: gate.wait(30)
    p = _player(g)
    assert p.start(_circle(0.05), FS, PlaySettings(mode="lockstep"))[0]
    p.stop(join=False)
    gate.set()
    p.stop()                                      # joins
    assert not p.playing and not g.sent and g.states[-1]["state"] == "stopped"


@pytest.mark.parametrize("values,field", [
    ({"mode": "fast"}, "mode"), ({"block_size": 0}, "block_size"), ({"block_size": 2.0}, "block_size"),
    ({"block_size": 20001}, "block_size"), ({"window": 0}, "window"), ({"preview_s": 1.5}, "preview_s"),
    ({"preview_s": True}, "preview_s"), ({"workspace_m": -1.0}, "workspace_m"),
    ({"workspace_m": math.inf}, "workspace_m"), ({"sample_rate": 0.0}, "sample_rate"),
    ({"lockstep_timeout": -1.0}, "lockstep_timeout"), ({"ack_timeout": "5"}, "ack_timeout"),
    ({"voltage_limit": False}, "voltage_limit"), ({"sample_rate": 30000.0}, "sample_rate")])
def test_bad_parameters_are_refused_naming_the_field(values, field):
    with pytest.raises(ConfigError) as exc:
        check_play_params(values)
    assert exc.value.field == field


def test_a_sample_rate_off_the_nanosecond_grid_is_refused_saying_why():
    """30 kHz has no whole-nanosecond period: its stamps would drift from k / fs."""
    with pytest.raises(ConfigError, match="^sample_rate: 30000.0 Hz has no whole-nanosecond period"):
        check_play_params({"sample_rate": 30000.0})


def test_good_parameters_pass_and_settings_check_theirs():
    check_play_params({"mode": "lockstep", "block_size": 20000, "window": 1, "preview_s": 0, "workspace_m": 0.0,
                       "sample_rate": 25000.0, "lockstep_timeout": 1, "ack_timeout": 0.1, "voltage_limit": 100,
                       "unrelated": object()})
    with pytest.raises(ConfigError, match="^window"):
        PlaySettings(window=0)


def test_parse_trajectory_names_the_field(tmp_path):
    with pytest.raises(ConfigError, match="^trajectory: empty"):
        parse_trajectory("")
    with pytest.raises(ConfigError, match="^trajectory_file: .*no such file"):
        parse_trajectory(file=str(tmp_path / "none.yaml"))
    with pytest.raises(ConfigError, match="^trajectory.radius: .*outside the workspace"):
        parse_trajectory('{"type": "circle", "radius": 1.0e-3, "frequency": 1.0}', workspace_m=1e-4)
    np.save(tmp_path / "t.npy", np.zeros((10, 2)))
    assert parse_trajectory(file=str(tmp_path / "t.npy")).n_samples(FS) == 10


def test_a_period_that_is_not_a_positive_integer_is_refused():
    with pytest.raises(ValueError, match="period_ns"):
        TrajectoryPlayer(FakeGraph(), 0)


def test_a_start_as_soon_as_finished_is_heard_is_accepted():
    """A client starts the next run the moment it hears ``finished`` (commissioning does, experiment after
    experiment); the play thread may still be winding up (its last log line, on a loaded host).  Seen in a full-suite
    run: ``/trajectory/start: already playing``.  Once the state says the run ended, a new start is accepted."""
    g = FakeGraph()
    heard, release = threading.Event(), threading.Event()
    publish = g.publish_state

    def winding_up(state):
        publish(state)
        if state["state"] == "finished" and not heard.is_set():
            heard.set()
            release.wait(30)         # the play thread stays alive a moment after publishing its end

    g.publish_state = winding_up
    p = _player(g)
    assert p.start(_circle(0.05), FS, PlaySettings(mode="lockstep", block_size=100, window=4))[0]
    assert heard.wait(30)
    threading.Timer(0.2, release.set).start()
    ok, msg = p.start(_circle(0.05), FS, PlaySettings(mode="lockstep", block_size=100, window=4))
    assert ok, msg
    p.stop()
    assert [s["state"] for s in g.states if s["state"] in ("finished", "stopped")][0] == "finished"
