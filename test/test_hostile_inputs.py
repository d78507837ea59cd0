"""Hostile text and numbers without ROS: YAML with size, depth and alias limits enforced before any work, the safety
bounds the docs state, an analysis of a recording that holds an absurd sample."""
from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from piezo_ff_ros.core.config import ConfigError, LimitsConfig
from piezo_ff_ros.core.config.loader import YAML_MAX_DEPTH, load_config, safe_yaml
from piezo_ff_ros.core.parameter_book import CONFIG_YAML_MAX_BYTES, parse_config_yaml

ROOT = Path(__file__).resolve().parents[1]


def alias_bomb(levels: int = 9) -> str:
    """The "billion laughs": each level 9 aliases of the previous one (≈ 600 characters, 9**levels leaves)."""
    lines = ['a0: &a0 ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
    for i in range(1, levels + 1):
        lines.append(f"a{i}: &a{i} [" + ",".join([f"*a{i - 1}"] * 9) + "]")
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("case", ["deep 1000", "deep flow 5000", "alias bomb", "8 MB string"])
def test_config_yaml_bombs_are_refused_with_one_line_at_once(case):
    text = {"deep 1000": "{a: " * 1000 + "1" + "}" * 1000,   # 5 kB
            "deep flow 5000": "[" * 5000 + "]" * 5000,
            "alias bomb": alias_bomb(),
            "8 MB string": "x: '" + "a" * (8 << 20) + "'"}[case]
    t0 = time.perf_counter()
    with pytest.raises(ConfigError) as err:
        parse_config_yaml(text)
    took = time.perf_counter() - t0
    msg = str(err.value)
    assert msg.startswith("config_yaml:") and "\n" not in msg, msg
    assert took < 5.0, f"{case}: {took:.2f} s"   # refused before any real work (was 25–33 s; noisy machine)


def test_yaml_limits_and_what_still_parses():
    assert safe_yaml("a: {b: [1, 2]}\nc: &x [1]\nd: *x\n", "t") == {"a": {"b": [1, 2]}, "c": [1], "d": [1]}
    nested = "[" * YAML_MAX_DEPTH + "]" * YAML_MAX_DEPTH
    assert safe_yaml(nested, "t") is not None
    with pytest.raises(ConfigError, match=r"^t: YAML nested deeper"):
        safe_yaml("[" + nested + "]", "t")
    with pytest.raises(ConfigError, match="alias bomb"):
        safe_yaml(alias_bomb(6), "t")
    with pytest.raises(ConfigError, match="duplicate key"):
        safe_yaml("a: 1\na: 2\n", "t")
    with pytest.raises(ConfigError, match="bytes of YAML"):
        parse_config_yaml("#" * (CONFIG_YAML_MAX_BYTES + 1))
    # every stage parameter of the paper's configuration still goes through config_yaml
    import yaml

    from piezo_ff_ros.core.param_map import config_to_params

    params = config_to_params(load_config(ROOT / "config" / "pt230_94.yaml"))
    assert parse_config_yaml(yaml.safe_dump(params)) == params


def test_config_files_are_limited_too(tmp_path):
    p = tmp_path / "bomb.yaml"
    p.write_text(alias_bomb())
    with pytest.raises(ConfigError, match="alias bomb"):
        load_config(p)
    big = tmp_path / "big.yaml"
    big.write_bytes(b"#" * (2 << 20))
    with pytest.raises(ConfigError, match="more than"):
        load_config(big)


# ---------------------------------------------------------------------------------------------------------------
# the documented safety bounds

#: every bound docs/nodes.md states for the driver: (parameter, value just outside, value on the bound, doc text)
DOCUMENTED = [
    ("safe_ramp.duration", 0.0, 0.05, "`safe_ramp.duration` ≥ 0.05 s"),
    ("safe_ramp.slew", 1.0e12, 1.0e4, "`safe_ramp.slew` ≤ 1e4 V/s"),
    ("safe_ramp.slew", 0.0, 1.0e4, "`safe_ramp.slew` ≤ 1e4 V/s"),
]


def _driver_settings(name, value):
    from piezo_ff_ros.core.hardware import DriverSettings
    from piezo_ff_ros.core.safety import SafeRampConfig

    ramp = replace(SafeRampConfig(), **{name.split(".")[1]: value})
    return DriverSettings(sample_rate=20000.0, n_axes=2, limits=LimitsConfig(), ramp=ramp)


@pytest.mark.parametrize("name, outside, bound, doc", DOCUMENTED)
def test_every_documented_driver_bound_is_enforced(name, outside, bound, doc):
    docs = (ROOT / "docs" / "nodes.md").read_text()
    assert doc in docs, f"docs/nodes.md no longer states {doc!r}"
    _driver_settings(name, bound).validate()
    with pytest.raises(ConfigError, match=name.replace(".", r"\.")):
        _driver_settings(name, outside).validate()


# ---------------------------------------------------------------------------------------------------------------
# analyze


def _recording(path, poison=None):
    from piezo_ff_ros.core.recording import blocks as B
    from piezo_ff_ros.core.recording.mcap_io import McapRecorder

    rng = np.random.default_rng(0)
    with McapRecorder(path) as rec:
        rec.set_metadata({"sample_rate": 20000, "t0_ns": 0, "axes": ["x", "y"]})
        for role in ("reference", "voltage", "displacement"):
            rec.register_topic(f"/{role}", B.BLOCK_TYPE)
        for k0 in range(0, 4000, 200):
            for role, scale in (("reference", 1e-6), ("voltage", 20.0), ("displacement", 1e-6)):
                blk = rng.standard_normal((200, 2)) * scale
                if poison and role == poison[0] and k0 == 400:
                    blk[3, 0] = poison[1]
                if role == "voltage" and k0 == 800:
                    blk[:10, 1] = 200.0           # ten samples at the limit
                rec.write(f"/{role}", B.serialize_block(blk, k0 * 50_000), 0)
    return path


@pytest.mark.parametrize("poison", [("reference", 1e308), ("displacement", -1e300), ("voltage", 1e308),
                                    ("reference", np.inf)])
def test_analyze_of_a_recording_with_an_absurd_sample_is_clean(tmp_path, capsys, poison):
    import json

    from piezo_ff_ros.cli import main as cli_main

    path = _recording(tmp_path / "run.mcap", poison)
    assert cli_main(["analyze", str(path), "--json", str(tmp_path / "a.json")]) == 0
    out, err = capsys.readouterr()
    assert "internal error" not in out + err and "Traceback" not in out + err
    rep = json.loads((tmp_path / "a.json").read_text())["replay"]
    assert all(np.isfinite(v) for v in rep["tracking"]["rms"])
    sat = rep["saturation"]["samples"]
    assert sat == 10 + int(poison == ("voltage", 1e308))   # the absurd voltage is at the limit too
    if np.isfinite(poison[1]):
        assert any("not a plausible value" in w for w in rep["warnings"])
