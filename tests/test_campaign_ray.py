"""Campaigns on a local Ray (the `ray` extra, installed by the Makefile so CI runs these): after the driver
is killed mid-campaign, the campaign resumes on a new local Ray with every run exactly once.

Every step runs in a subprocess with a time limit, so a stuck Ray cannot hang the suite. With
``OMNIROTOR_REQUIRE_RAY=1`` (set by ``.ci/run``) a missing ray is a failure, not a skip.
"""

import contextlib
import importlib.util
import json
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest

from test_campaign_signals import campaign_argv

HAVE_RAY = importlib.util.find_spec("ray") is not None
if not HAVE_RAY and os.environ.get("OMNIROTOR_REQUIRE_RAY") == "1":
    raise RuntimeError("OMNIROTOR_REQUIRE_RAY=1 but ray is not installed (pip install -e '.[ray]')")
pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(not HAVE_RAY, reason="ray (the optional 'ray' extra) is not installed"),
]

START_TIMEOUT_S = 300
RUN_TIMEOUT_S = 400


def cli(tmp_path, out, *extra):
    return campaign_argv(tmp_path, out, "--backend", "ray", "--workers", "2", *extra)


def group_alive(pgid):
    """Pids (not zombies) still in process group ``pgid``."""
    pids = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            with contextlib.suppress(OSError, IndexError, ValueError):
                fields = Path(f"/proc/{entry}/stat").read_text().rsplit(")", 1)[1].split()
                if int(fields[2]) == pgid and fields[0] != "Z":
                    pids.append(int(entry))
    return pids


def indices(out):
    p = out / "results.jsonl"
    return [json.loads(x)["index"] for x in p.read_text().split("\n")[:-1]] if p.exists() else []


def test_ray_campaign_resumes_after_its_driver_is_killed(tmp_path):
    out = tmp_path / "c"
    argv, env = cli(tmp_path, out)
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env, start_new_session=True)
    try:
        deadline = time.monotonic() + START_TIMEOUT_S
        while not indices(out) and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.5)
        assert indices(out), f"no run finished on Ray (exit {proc.poll()})"
        os.kill(proc.pid, signal.SIGKILL)  # the driver only
        proc.communicate(timeout=60)
    finally:
        # Ray's raylet and GCS share the driver's fate, but its dashboard and runtime-env agents can linger
        # for minutes: stop what is left of this Ray (as `ray stop` would), so the suite leaves nothing behind.
        for pid in group_alive(proc.pid):
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)
        if proc.poll() is None:
            proc.kill()
            proc.communicate(timeout=30)
    before = sorted(set(indices(out)))
    n = len(before) + 2
    argv, env = cli(tmp_path, out, "--runs", str(n), "--json")
    r = subprocess.run(argv, capture_output=True, text=True, env=env, timeout=RUN_TIMEOUT_S, start_new_session=True)
    assert r.returncode == 0, r.stderr[-2000:]
    summary = json.loads(r.stdout)
    assert summary["runs_done"] == n and summary["executed"] == n - len(before)
    idx = indices(out)
    assert sorted(idx) == sorted(set(idx)) and set(range(n)) <= set(idx)  # every run exactly once
