"""The test command (scripts/test.sh) runs a test once more only for the two symptoms of a node process that stopped
answering DDS — a service reply that never came (``Probe.call``) and a node killed after ignoring SIGINT
(``assert stop_node(p) == 0``, or an exit code -9 among several nodes' codes) — and any other failure fails at once."""
import re
import shlex
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _rerun_options():
    text = (ROOT / "scripts" / "test.sh").read_text()
    line = text[text.index("exec .venv/bin/python -m pytest"):].replace("\\\n", " ").splitlines()[0]
    words = shlex.split(line)
    i = words.index("--reruns")
    return [w for w in words[i:] if w != '"$@"' and w != "$@"]


SAMPLE = '''
import os
from pathlib import Path
import pytest

MARK = Path(os.environ["RERUN_MARK_DIR"])


def _first_time(name):
    f = MARK / name
    if f.exists():
        return False
    f.write_text("x")
    return True


def test_a_reply_that_never_came():
    if _first_time("reply"):
        raise AssertionError("timed out after 60 s waiting for reply of /trajectory/get_parameters")


def stop_node(p):
    return -9 if _first_time("stop") else 0


def test_a_node_that_ignored_sigint():
    assert stop_node(None) == 0


def test_nodes_stopped_together_one_ignored_sigint():
    codes = [-9, 0, 0] if _first_time("codes") else [0, 0, 0]
    assert codes == [0, 0, 0]


def test_nodes_stopped_by_name_one_ignored_sigint():
    codes = {"compensator": 0, "trajectory": -9, "recorder": 0} if _first_time("dict") else \
        {"compensator": 0, "trajectory": 0, "recorder": 0}
    assert codes == {"compensator": 0, "trajectory": 0, "recorder": 0}


def test_a_small_number_is_not_an_exit_code():
    if _first_time("small"):
        assert 3.2e-9 == 0


def test_any_other_failure():
    if _first_time("other"):
        assert 1 + 1 == 3
'''


def test_only_the_unresponsive_node_symptoms_are_rerun(tmp_path):
    opts = _rerun_options()
    assert opts[:2] == ["--reruns", "1"], opts
    (tmp_path / "test_sample.py").write_text(SAMPLE)
    marks = tmp_path / "marks"
    marks.mkdir()
    out = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-rfR", *opts,
                          str(tmp_path / "test_sample.py")], cwd=tmp_path, capture_output=True, text=True,
                         env={**__import__("os").environ, "RERUN_MARK_DIR": str(marks)}).stdout
    last = out.strip().splitlines()[-1]
    assert re.search(r"2 failed, 4 passed, 4 rerun", last), out[-3000:]
    assert "FAILED test_sample.py::test_any_other_failure" in out, out[-3000:]
    assert "FAILED test_sample.py::test_a_small_number_is_not_an_exit_code" in out, out[-3000:]
