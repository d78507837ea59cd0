"""What ``diagnose --apply`` says it did to the hysteresis stage is what it did: a Bouc-Wen Δ1/Δ2 fit is written to
the config with its values; an added Preisach relay plane or play-operator loop, which no compensator stage of the
cascade can invert, leaves the hysteresis config unchanged and says so."""
import numpy as np
import pytest

from piezo_ff_ros.core.config import load_config
from piezo_ff_ros.core.diagnosis.report import corrected_config


@pytest.fixture(scope="module")
def cfg():
    return load_config()


def test_a_bouc_wen_asymmetry_is_written_and_its_values_named(cfg):
    new, _, notes = corrected_config(cfg, [("hysteresis_asymmetry", {"Delta1": [0.02, -0.01], "Delta2": [0.0, 0.0]})])
    assert new.hysteresis != cfg.hysteresis
    (note,) = notes
    assert note.startswith("hysteresis_asymmetry: Δ1 = [0.02, -0.01], Δ2 = [0.0, 0.0] added")


@pytest.mark.parametrize("extra", [
    {"relay_alpha": [0.0, 10.0], "relay_beta": [-10.0, 0.0], "relay_gains": [[1e-8, 2e-8], [3e-8, 4e-8]]},
    {"input_even": [1e-8, 0.0], "input_play_radii": [20.0], "input_play_gains": [[1e-8, 1e-8]],
     "input_play_level_gains": [[0.0, 0.0]]},
])
def test_an_added_loop_of_another_form_is_not_claimed_as_compensated(cfg, extra):
    p = dict({"Delta1": [0.0, 0.0], "Delta2": [0.0, 0.0]}, **extra)
    new, _, notes = corrected_config(cfg, [("hysteresis_asymmetry", p)])
    assert np.array_equal(np.asarray(new.to_dict("um")["hysteresis"], dtype=object),
                          np.asarray(cfg.to_dict("um")["hysteresis"], dtype=object))
    (note,) = notes
    assert "Δ1/Δ2 added" not in note
    assert "no compensator" in note and "hysteresis config unchanged" in note


def test_a_slew_limit_measured_per_direction_writes_the_slower_one(cfg):
    """An amplifier that rises at 1341 V/s and falls at 737 V/s: the driver's one slew limit must be the falling
    rate, else the compensator plans falls the amplifier cannot follow."""
    new, _, notes = corrected_config(cfg, [("amplifier_slew_limit", {"rate": 1341.0, "rate_down": 737.0})])
    assert new.limits.slew == 737.0
    (note,) = notes
    assert "737" in note and "1341" in note
    new, _, _ = corrected_config(cfg, [("amplifier_slew_limit", {"rate": 1200.0})])
    assert new.limits.slew == 1200.0
