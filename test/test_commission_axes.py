"""Commissioning, identification and the tables on stages of one, two and three axes (core sim, no ROS)."""
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from piezo_ff_ros.core.characterisation import CharacterisationSettings
from piezo_ff_ros.core.commissioning import CommissioningError, SimRig, commission
from piezo_ff_ros.core.config import load_config
from piezo_ff_ros.core.models.plant import Plant

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "config"
#: short characterisation: seconds of creep, one short hysteresis period (the sequence, not the figures, is tested)
SHORT = CharacterisationSettings(creep_duration=3.0, sine_frequency=1.0, sine_periods=1, plant_validation_duration=2.0,
                                 plant_validation_hold=0.5)


def test_a_starting_config_whose_axes_differ_from_the_rigs_is_refused():
    xyz = load_config(CONFIG / "xyz_tube.yaml")
    paper = load_config()
    rig = SimRig(Plant(xyz), xyz.sample_rate, xyz.axes)
    with pytest.raises(CommissioningError) as exc:
        commission(rig, base=paper, settings=SHORT)
    msg = str(exc.value)
    assert "\n" not in msg and "['x', 'y']" in msg and "['x', 'y', 'z']" in msg


@pytest.mark.parametrize("name, axes", [("single_stack", ("x",)), ("xyz_tube", ("x", "y", "z"))])
def test_commission_identifies_every_axis_and_pair_of_the_configured_stage(name, axes):
    cfg = load_config(CONFIG / f"{name}.yaml")
    rig = SimRig(Plant(cfg), cfg.sample_rate, cfg.axes)
    res = commission(rig, base=cfg, settings=SHORT, creep_order=2, dynamics_order="auto",
                     synthesize=True)
    assert res.config.axes == axes and res.config.name == f"{name}_identified"
    pairs = {o + i for o in axes for i in axes}
    assert set(res.report.fit_percent["hysteresis"]) == set(axes)
    assert set(res.report.fit_percent["creep"]) == pairs and set(res.report.fit_percent["dynamics"]) == pairs
    assert set(res.report.fit_percent["plant"]) == set(axes)
    # one creep and one dynamics characterisation step per axis, a hysteresis sine per axis
    names = {r.meta["experiment"] for r in res.runs}
    for a in axes:
        assert {f"sine_{a}", f"creep_step_{a}", f"dynamics_step_{a}"} <= names
    assert min(res.report.fit_percent["hysteresis"].values()) > 90
    assert min(res.report.fit_percent["dynamics"][a + a] for a in axes) > 90
    ctrl = res.config.vibration.controller
    assert np.asarray(ctrl["B"]).shape[1] == len(axes) and np.asarray(ctrl["C"]).shape[0] == len(axes)


@pytest.mark.parametrize("n", [1, 2, 3, 6])
def test_the_characterisation_plan_is_generated_from_the_axes(n):
    """Per axis a hysteresis sine, a creep and a dynamics step; the runs moving several axes: one with two axes (the
    paper's), one per pair from three on; the held-out runs move every axis."""
    from piezo_ff_ros.core.commissioning import characterisation_plan

    axes = tuple("xyzabc"[:n])
    plan = characterisation_plan(CharacterisationSettings(), axes)
    names = [r.name for r in plan["hysteresis"] if r.role == "fit"]
    pairs = [f"sine_{a}{b}" for i, a in enumerate(axes) for b in axes[i + 1:]] if n > 2 else (
        ["sine_all"] if n == 2 else [])
    assert names == [f"sine_{a}" for a in axes] + pairs
    assert [r.name for r in plan["creep"]] == [f"creep_step_{a}" for a in axes]
    assert [r.name for r in plan["dynamics"]] == [f"dynamics_step_{a}" for a in axes]
    fs = 2000.0
    for r in plan["hysteresis"] + plan["plant"]:
        assert r.trajectory.axes == axes
    _, val = next(r for r in plan["hysteresis"] if r.role == "validation").trajectory.sample(fs)
    assert np.all(np.ptp(val, axis=0) > 100)   # every axis moves in the held-out run
    _, pv = plan["plant"][0].trajectory.sample(fs)
    assert np.all(np.ptp(pv, axis=0) > 100) and np.abs(pv).max() <= 200
