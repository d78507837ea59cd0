"""Two concurrent test sessions never share a ROS domain (conftest.claim_test_domain)."""
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_two_sessions_get_different_domains():
    code = ("import sys, time; sys.path.insert(0, 'test'); import conftest as c; d, f = c.claim_test_domain(1, 3); "
            "print(d, flush=True); time.sleep(float(sys.argv[1]))")
    env = dict(os.environ, PIEZO_FF_TEST_DOMAIN="99")   # conftest's own claim at import stays out of the way
    a = subprocess.Popen([sys.executable, "-c", code, "5"], cwd=ROOT, stdout=subprocess.PIPE, text=True, env=env)
    first = a.stdout.readline().strip()
    b = subprocess.run([sys.executable, "-c", code, "0"], cwd=ROOT, capture_output=True, text=True, timeout=60,
                       env=env)
    a.kill()
    a.wait()
    assert first and b.stdout.strip() and first != b.stdout.strip(), (first, b.stdout, b.stderr)
