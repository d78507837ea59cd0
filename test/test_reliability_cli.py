"""The commands that printed a traceback now print one line and exit non-zero.

Each case was a traceback before (output path is a directory for ``analyze --json``, ``diagnose --json``,
``check --json`` and ``check DIR``; ``demo --out EXISTING_FILE``; an infeasible H∞ config accepted by ``check``,
then a ``HinfSynthesisError`` traceback from ``reproduce`` and "no block topic" from ``demo``).
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from piezo_ff_ros.cli import CliError, main as cli_main

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "config" / "pt230_94.yaml"


def _one_line_error(capsys, *needles: str) -> str:
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err
    assert err.count("\n") == 0, err
    assert ": error: " in err, err
    for n in needles:
        assert n in err, err
    return err


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory) -> Path:
    from piezo_ff_ros.core.recording import blocks as B
    from piezo_ff_ros.core.recording.mcap_io import McapRecorder

    path = tmp_path_factory.mktemp("run") / "run.mcap"
    rng = np.random.default_rng(0)
    with McapRecorder(path) as rec:
        rec.set_metadata({"sample_rate": 20000, "t0_ns": 0, "axes": ["x", "y"]})
        for role in ("reference", "voltage", "displacement"):
            rec.register_topic(f"/{role}", B.BLOCK_TYPE)
        for k0 in range(0, 4000, 200):
            for role, scale in (("reference", 1e-6), ("voltage", 50.0), ("displacement", 1e-6)):
                rec.write(f"/{role}", B.serialize_block(rng.standard_normal((200, 2)) * scale, k0 * 50_000), 0)
    return path


@pytest.fixture(scope="module")
def infeasible_config(tmp_path_factory) -> Path:
    text = PAPER.read_text().replace("gamma_max: 1.0 ", "gamma_max: 0.5 ")
    assert "gamma_max: 0.5" in text
    p = tmp_path_factory.mktemp("cfg") / "infeasible.yaml"
    p.write_text(text)
    return p


def test_analyze_json_into_a_directory(tiny_run, tmp_path, capsys):
    assert cli_main(["analyze", str(tiny_run), "--json", str(tmp_path)]) == 2
    _one_line_error(capsys, "--json", "is a directory")


def test_diagnose_json_into_a_directory(tiny_run, tmp_path, capsys):
    assert cli_main(["diagnose", "--data", str(tiny_run), "--json", str(tmp_path)]) == 2
    _one_line_error(capsys, "--json", "is a directory")


def test_check_with_a_directory(tmp_path, capsys):
    assert cli_main(["check", str(tmp_path)]) == 2
    _one_line_error(capsys, str(tmp_path), "directory")
    assert cli_main(["check", "--no-synthesis", "--json", str(tmp_path)]) == 2
    _one_line_error(capsys, "--json", "is a directory")


def test_demo_out_is_an_existing_file(tmp_path, capsys):
    f = tmp_path / "file.txt"
    f.write_text("x")
    assert cli_main(["demo", "--out", str(f)]) == 2
    _one_line_error(capsys, "--out", "not a directory")


def test_check_says_infeasible_and_exits_nonzero(infeasible_config, capsys):
    assert cli_main(["check", str(infeasible_config)]) == 2
    err = _one_line_error(capsys, "infeasible", "gamma_max")
    assert "0.5" in err
    assert cli_main(["check", str(PAPER)]) == 0
    assert "H∞: γ = 0.948" in capsys.readouterr().out


def test_reproduce_infeasible_is_one_line(infeasible_config, capsys):
    assert cli_main(["reproduce", "--config", str(infeasible_config), "--creep-duration", "2", "--no-robustness",
                     "--quiet"]) == 2
    _one_line_error(capsys, "infeasible", "gamma_max")


def test_demo_infeasible_names_the_cause_before_starting_the_graph(infeasible_config, tmp_path, capsys):
    assert cli_main(["demo", "--config", str(infeasible_config), "--out", str(tmp_path / "d"), "--quiet"]) == 2
    err = _one_line_error(capsys, "infeasible", "gamma_max")
    assert "no block topic" not in err


def test_internal_errors_are_one_line_too(monkeypatch, capsys):
    import piezo_ff_ros.cli.check as check

    def boom(args):
        raise KeyError("a defect")

    monkeypatch.setattr(check, "run", boom)
    parser_args = ["check"]
    from piezo_ff_ros import cli

    real = cli.build_parser

    def patched(*args):
        p = real(*args)
        p._subparsers._group_actions[0].choices["check"].set_defaults(func=boom)
        return p

    monkeypatch.setattr(cli, "build_parser", patched)
    assert cli_main(parser_args) == 1
    err = capsys.readouterr().err
    assert "Traceback" not in err and "internal error: KeyError" in err and err.count("\n") == 1


def test_cli_error_is_exit_2(monkeypatch, capsys):
    from piezo_ff_ros import cli

    real = cli.build_parser

    def patched(*args):
        p = real(*args)
        p._subparsers._group_actions[0].choices["check"].set_defaults(
            func=lambda a: (_ for _ in ()).throw(CliError("--x: bad\nsecond line")))
        return p

    monkeypatch.setattr(cli, "build_parser", patched)
    assert cli_main(["check"]) == 2
    assert capsys.readouterr().err == "piezo-ff check: error: --x: bad second line\n"


def test_console_entry_point_never_prints_a_traceback(tmp_path):
    """The real process: python -m piezo_ff_ros with a directory as output."""
    proc = subprocess.run([sys.executable, "-m", "piezo_ff_ros", "check", "--no-synthesis", "--json", str(tmp_path)],
                          capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr and proc.stderr.count("\n") == 1
