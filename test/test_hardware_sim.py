"""The simulator behind the streaming backend contract (core/hardware/simulated_device.py): lockstep and clocked modes."""
import numpy as np
import pytest

from piezo_ff_ros.core.hardware import ClockedSim, ContractError, Disconnect, LockstepSim, Overrun, Underrun

FS = 20000.0


class Gain:
    """A memoryless 'plant' y = 1e-7·u (so that every sample can be checked) with a call log."""

    def __init__(self):
        self.calls = 0

    def process(self, u):
        self.calls += 1
        return 1e-7 * np.asarray(u)

    def reset(self):
        self.calls = 0


class FakeClock:
    def __init__(self):
        self.n = 0

    def __call__(self):
        return self.n / FS

    def advance(self, samples):
        self.n += samples


def concat(blocks, n_axes=2):
    """(k0, block) list → (first index, stacked array), asserting contiguity."""
    if not blocks:
        return None, np.zeros((0, n_axes))
    k = blocks[0][0]
    for k0, b in blocks:
        assert k0 == k, "blocks not contiguous"
        k += b.shape[0]
    return blocks[0][0], np.vstack([b for _, b in blocks])


def test_lockstep_write_is_output_and_measured_at_once_and_contiguity_enforced():
    sim = LockstepSim(FS, 2, Gain())
    assert sim.start(np.zeros(2)) == 0
    u = np.arange(20.0).reshape(10, 2)
    sim.write(0, u)
    assert sim.clock() == sim.write_index == 10
    (k0, y), = sim.read()
    assert k0 == 0
    np.testing.assert_array_equal(y, 1e-7 * u)
    (k0, a), = sim.take_applied()
    np.testing.assert_array_equal(a, u)
    with pytest.raises(ContractError, match="expected 10"):
        sim.write(5, u)


def test_clocked_outputs_at_the_clock_rate_with_latency_and_every_sample_once():
    clk = FakeClock()
    sim = ClockedSim(FS, 2, Gain(), fifo_depth=1000, latency_samples=7, now=clk)
    sim.start(np.zeros(2))
    u = np.random.default_rng(1).normal(size=(3000, 2))
    w = 0
    got_y, got_a = [], []
    for _ in range(60):  # write ahead in chunks of what fits, advance the clock by 50 samples per step
        space = sim.write_space()
        if w < len(u) and space:
            part = u[w:w + space]
            sim.write(w, part)
            w += part.shape[0]
        clk.advance(50)
        sim.poll()
        got_y += sim.read()
        got_a += sim.take_applied()
        assert sim.write_index - sim.clock() <= 1000   # never more than the FIFO ahead
    k0, a = concat(got_a)
    assert k0 == 0 and a.shape[0] == 3000
    np.testing.assert_array_equal(a, u)
    k0, y = concat(got_y)
    assert k0 == 0 and y.shape[0] == 3000 - 7          # the last 7 not yet readable: latency
    np.testing.assert_array_equal(y, 1e-7 * u[:y.shape[0]])
    assert sim.counters["underruns"] == 0


def test_clocked_underrun_holds_last_value_and_is_raised_typed():
    clk = FakeClock()
    sim = ClockedSim(FS, 2, Gain(), fifo_depth=500, latency_samples=0, now=clk)
    sim.start(np.zeros(2))
    sim.write(0, np.full((100, 2), 3.0))
    clk.advance(250)
    with pytest.raises(Underrun) as exc:
        sim.poll()
    assert exc.value.k == 100
    _, a = concat(sim.take_applied())
    assert a.shape[0] == 250 and np.all(a == 3.0)        # the DAC held 3 V for the 150 missing samples
    assert sim.counters["underrun_samples"] == 150
    assert sim.write_index == 250                          # the held samples are past: write from the clock on
    sim.write(250, np.ones((10, 2)))
    with pytest.raises(ContractError, match="FIFO space"):
        sim.write(260, np.ones((501, 2)))


def test_clocked_overrun_when_sensor_not_read_and_disconnect_is_permanent():
    clk = FakeClock()
    sim = ClockedSim(FS, 1, Gain(), fifo_depth=10000, latency_samples=0, input_buffer=1000, now=clk)
    sim.start(np.zeros(1))
    sim.write(0, np.ones((5000, 1)))
    clk.advance(3000)
    with pytest.raises(Overrun):
        sim.poll()
    k0, y = concat(sim.read(), 1)
    assert k0 == 2000 and y.shape[0] == 1000               # only the newest input_buffer samples survive
    sim.inject("disconnect")
    with pytest.raises(Disconnect):
        sim.poll()
    with pytest.raises(Disconnect):
        sim.write(sim.write_index, np.ones((1, 1)))


def test_clocked_jitter_delays_delivery_but_loses_nothing():
    clk = FakeClock()
    sim = ClockedSim(FS, 1, Gain(), fifo_depth=100000, latency_samples=3, jitter_samples=40, now=clk, seed=3)
    sim.start(np.zeros(1))
    u = np.arange(4000.0)[:, None]
    sim.write(0, u)
    got = []
    for _ in range(100):
        clk.advance(37)
        got += sim.read()
    k0, y = concat(got, 1)
    assert k0 == 0 and y.shape[0] >= 3700 - 3 - 40
    np.testing.assert_array_equal(y[:, 0], 1e-7 * u[:y.shape[0], 0])


def test_clocked_parameters_validated():
    with pytest.raises(ValueError, match="fifo_depth"):
        ClockedSim(FS, 2, fifo_depth=0)
    with pytest.raises(ValueError, match="latency_samples"):
        ClockedSim(FS, 2, latency_samples=-1)


@pytest.mark.parametrize("scale", [0.5, 1.0, 10.0, 250.0])
def test_clocked_time_scale_runs_the_device_clock_that_many_times_faster(scale):
    clk = FakeClock()            # now() = clk.n / FS seconds
    sim = ClockedSim(FS, 2, Gain(), fifo_depth=1 << 20, latency_samples=0, now=clk, time_scale=scale)
    sim.start(np.zeros(2), prefill=0)
    sim.write(0, np.ones((1 << 19, 2)))
    clk.advance(1000)            # 0.05 s of now()
    sim.poll()
    assert sim.clock() == int(1000 * scale)
    _, a = concat(sim.take_applied())
    assert a.shape[0] == int(1000 * scale)   # every device sample output once, whatever the speed


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf"), 1e4])
def test_clocked_time_scale_validated(bad):
    with pytest.raises(ValueError, match="time_scale"):
        ClockedSim(FS, 2, Gain(), time_scale=bad)


def test_clocked_reset_restarts_the_stream_at_rest():
    clk = FakeClock()
    sim = ClockedSim(FS, 2, Gain(), fifo_depth=1000, latency_samples=0, now=clk)
    sim.start(np.zeros(2))
    sim.write(0, np.full((300, 2), 2.0))
    clk.advance(200)
    sim.poll()
    sim.read()
    assert sim.reset()
    assert sim.start(np.zeros(2), prefill=10) == 10          # index 0 again, prefilled with the safe voltage
    sim.write(10, np.full((50, 2), 1.0))
    clk.advance(60)
    sim.poll()
    k0, a = concat(sim.take_applied())
    assert k0 == 0 and a.shape[0] == 60
    np.testing.assert_array_equal(a, np.vstack([np.zeros((10, 2)), np.ones((50, 2))]))   # nothing of before
    k0, y = concat(sim.read())
    assert k0 == 0 and y.shape[0] == 60
