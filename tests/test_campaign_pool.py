"""The resident campaign worker pool (``omnirotor workers start|status|stop``; issue #16, campaign throughput).

A campaign handed to the pool must give the command's own records, summary and plots, run by run; a pool started
from other sources must refuse; the command falls back to its own pool; the pool stops cleanly (its workers with
it), on ``stop`` and after its idle timeout; bad input through the pool is one line on stderr and exit status 2.
Every pool here lives in its own cache folder, never the user's.
"""

from __future__ import annotations

import collections
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from omnirotor.experiments import campaign_pool as cp

SRC = Path(__file__).resolve().parents[1] / "src"
TIMING = "step_us"
"""Metrics measured by the wall clock (a run's controller step time): never reproducible, left out."""

CAMPAIGN = """
task = "hover"
seed = 11
[options]
quick = true
duration_s = 1.0
[vary.gamma]
dist = "uniform"
low = 2.0
high = 8.0
[vary.mass_error]
dist = "normal"
std = 0.03
[vary.mocap_dropout_s]
dist = "choice"
values = [0.0, 0.2]
"""


@pytest.fixture
def cache(monkeypatch):
    """A short private cache folder (Unix socket paths are limited to about 100 bytes); any pool in it is stopped."""
    folder = tempfile.mkdtemp(prefix="omr-", dir="/tmp")
    monkeypatch.setenv("XDG_CACHE_HOME", folder)
    yield Path(folder)
    with pytest.MonkeyPatch.context() as m:
        m.setenv("XDG_CACHE_HOME", folder)
        cp.stop_pool()
    shutil.rmtree(folder, ignore_errors=True)


def cli(*args: str, cache: Path, cwd: Path | None = None) -> subprocess.CompletedProcess:
    """``omnirotor ARGS`` in a new interpreter with this checkout's sources and the private cache folder."""
    env = dict(os.environ, XDG_CACHE_HOME=str(cache), PYTHONPATH=str(SRC))
    code = "import sys; from omnirotor.cli import main; sys.exit(main())"
    return subprocess.run(
        [sys.executable, "-c", code, *args], capture_output=True, text=True, env=env, cwd=cwd, timeout=900
    )


def comparable(folder: Path) -> tuple[dict, dict]:
    """The results (by index) and the summary of a campaign folder, less the wall-clock figures."""

    def clean(obj):
        if isinstance(obj, dict):
            return {k: clean(v) for k, v in obj.items() if TIMING not in k and k not in ("elapsed_s", "plots")}
        return obj

    records = {}
    for line in (folder / "results.jsonl").read_text().splitlines():
        rec = json.loads(line)
        records[rec["index"]] = clean(rec)
    return records, clean(json.loads((folder / "summary.json").read_text()))


def test_client_side_imports_no_numpy_mujoco_or_numba():
    code = (
        "import sys, omnirotor.experiments.campaign_pool, omnirotor.cli.cmd_workers, omnirotor.cli.cmd_campaign; "
        "print([m for m in ('numpy', 'mujoco', 'numba', 'matplotlib') if m in sys.modules])"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         env=dict(os.environ, PYTHONPATH=str(SRC)))  # fmt: skip
    assert out.stdout.strip() == "[]"


def test_source_digest_changes_with_the_sources_and_numba_settings(tmp_path, monkeypatch):
    copy = tmp_path / "omnirotor"
    shutil.copytree(SRC / "omnirotor", copy, ignore=shutil.ignore_patterns("__pycache__"))
    monkeypatch.setattr(cp, "_package_dir", lambda: copy)
    monkeypatch.delenv("NUMBA_BOUNDSCHECK", raising=False)
    d0 = cp.source_digest()
    assert cp.source_digest() == d0  # deterministic
    (copy / "vehicle.py").write_text((copy / "vehicle.py").read_text() + "\n# edited\n")
    d1 = cp.source_digest()
    assert d1 != d0
    (copy / "presets" / "campaigns" / "default.toml").write_text("runs = 3\n")
    d2 = cp.source_digest()
    assert d2 != d1
    monkeypatch.setenv("NUMBA_BOUNDSCHECK", "1")
    assert cp.source_digest() != d2


def test_a_pool_from_other_sources_refuses_and_the_command_says_so(cache, monkeypatch, capsys):
    st = cp.start_pool(1, 60.0, warm=False)
    assert st["pid"] > 0 and not st["already"] and cp.pool_status()["current"]
    monkeypatch.setattr(cp, "source_digest", lambda: "edited-sources")
    assert cp.pool_status()["current"] is False
    assert cp.resident_campaign({"task": "hover"}, None) is None
    assert "started from other sources" in capsys.readouterr().err
    monkeypatch.undo()
    monkeypatch.setenv("XDG_CACHE_HOME", str(cache))
    again = cp.start_pool(1, 60.0, warm=False)
    assert again["already"] and again["pid"] == st["pid"]  # a current pool is kept, not started twice


def test_stop_ends_the_pool_and_its_workers_and_removes_the_socket(cache):
    st = cp.start_pool(2, 60.0, warm=False)
    assert cp.socket_path().exists()
    pid = cp.stop_pool()
    assert pid == st["pid"] and not cp._pid_alive(pid)
    assert not cp.socket_path().exists() and cp.pool_status() is None
    assert cp.stop_pool() is None  # nothing left to stop


def test_the_pool_exits_after_its_idle_timeout(cache):
    st = cp.start_pool(1, 1.0, warm=False)
    deadline = time.monotonic() + 20
    while cp._pid_alive(st["pid"]) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not cp._pid_alive(st["pid"])
    assert cp.pool_status() is None and not cp.socket_path().exists()


def test_campaign_on_the_pool_equals_the_commands_own_pool_run_by_run(cache, tmp_path):
    camp = tmp_path / "c.toml"
    camp.write_text(CAMPAIGN)
    local = cli("campaign", "--campaign", str(camp), "--runs", "6", "--workers", "2", "--out", "local",
                "--no-resident", cache=cache, cwd=tmp_path)  # fmt: skip
    assert local.returncode == 0, local.stderr
    assert "resident" not in local.stderr

    started = cli("workers", "start", "--workers", "2", cache=cache)
    assert started.returncode == 0 and "resident pool ready" in started.stdout, started.stderr
    status = cli("workers", "status", cache=cache)
    assert "serves this checkout" in status.stdout

    # a relative --out and campaign file: the pool works in the command's folder
    pooled = cli("campaign", "--campaign", "c.toml", "--runs", "6", "--workers", "2", "--out", "pooled",
                 cache=cache, cwd=tmp_path)  # fmt: skip
    assert pooled.returncode == 0, pooled.stderr
    assert "campaign on the resident worker pool" in pooled.stderr
    assert "throughput: 6.0 simulated s in" in pooled.stdout
    a_runs, a_summary = comparable(tmp_path / "local")
    b_runs, b_summary = comparable(tmp_path / "pooled")
    assert sorted(b_runs) == list(range(6))
    for i in a_runs:
        assert b_runs[i] == a_runs[i], f"run {i} differs between the resident pool and the command's own"
    assert b_summary == a_summary
    for png in sorted((tmp_path / "local" / "plots").glob("*.png")):
        assert (tmp_path / "pooled" / "plots" / png.name).read_bytes() == png.read_bytes(), png.name

    # resumed through the pool: nothing to run again
    again = cli("campaign", "--campaign", "c.toml", "--runs", "6", "--out", "pooled", "--json", cache=cache,
                cwd=tmp_path)  # fmt: skip
    assert again.returncode == 0 and json.loads(again.stdout)["executed"] == 0

    # bad input through the pool: one line, exit 2, the folder untouched
    bad = cli("campaign", "--campaign", "no-such-preset", "--out", "bad", cache=cache, cwd=tmp_path)
    assert bad.returncode == 2 and "Traceback" not in bad.stderr
    assert bad.stderr.strip().splitlines()[-1].startswith("omnirotor: error: unknown campaign 'no-such-preset'")
    assert not (tmp_path / "bad").exists()
    other = cli("campaign", "peg-in-hole", "--runs", "1", "--quick", "--out", "pooled", cache=cache, cwd=tmp_path)
    assert other.returncode == 2 and "holds another campaign" in other.stderr and "Traceback" not in other.stderr

    stopped = cli("workers", "stop", cache=cache)
    assert stopped.returncode == 0 and "resident pool stopped" in stopped.stdout
    assert "not running" in cli("workers", "status", cache=cache).stdout


def test_a_command_that_hangs_up_stops_its_campaign_and_the_pool_serves_the_next(cache, tmp_path, monkeypatch, capsys):
    camp = tmp_path / "c.toml"
    camp.write_text(CAMPAIGN)
    cp.start_pool(2, 120.0)
    monkeypatch.chdir(tmp_path)
    args = {"campaign_file": str(camp), "runs": 400, "out": str(tmp_path / "a")}
    run = cp.resident_campaign(args, None)
    assert run is not None and run.start["runs"] == 400
    next(msg for msg in run.runs() if msg["record"] is not None)  # one run finished
    # a second command meanwhile: refused (busy), so it runs its own pool
    assert cp.resident_campaign({"campaign_file": str(camp), "out": str(tmp_path / "x")}, None) is None
    assert "busy with another campaign" in capsys.readouterr().err
    run.close()  # as Ctrl-C does
    deadline = time.monotonic() + 60
    while cp.pool_status()["busy"] and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not cp.pool_status()["busy"]
    done = sum(1 for _ in (tmp_path / "a" / "results.jsonl").read_text().splitlines())
    assert 1 <= done < 400  # the runs not yet started never ran
    second = cp.resident_campaign({"campaign_file": str(camp), "runs": 2, "out": str(tmp_path / "b")}, None)
    assert second is not None
    assert sum(1 for m in second.runs() if m["record"] is not None) == 2
    assert second.result["type"] == "done" and second.result["summary"]["runs_done"] == 2
    second.close()


def test_a_worker_that_dies_fails_the_campaign_in_one_line_and_the_next_gets_fresh_workers(cache, tmp_path):
    camp = tmp_path / "c.toml"
    camp.write_text(CAMPAIGN)
    st = cp.start_pool(2, 120.0)
    run = cp.resident_campaign({"campaign_file": str(camp), "runs": 400, "out": str(tmp_path / "a")}, None)
    assert run is not None
    next(msg for msg in run.runs() if msg["record"] is not None)
    os.kill(st["worker_pids"][0], 9)  # a worker killed (out of memory, say)
    collections.deque(run.runs(), maxlen=0)  # follow the campaign to its end
    assert run.result["type"] == "error" and run.result["kind"] == "internal"
    run.close()
    again = cli("campaign", "--campaign", str(camp), "--runs", "2", "--out", "b", cache=cache, cwd=tmp_path)
    assert again.returncode == 0 and "campaign on the resident worker pool" in again.stderr, again.stderr
    new = cp.pool_status()["worker_pids"]
    assert len(new) == 2 and st["worker_pids"][0] not in new


def test_stop_executor_kills_busy_workers_and_leaves_nothing_for_the_exit_hook_to_wake():
    """A stopped pool's manager thread has ended and closed its wake-up pipe before ``stop_executor`` returns, so
    Python's exit hook (which writes to that pipe) cannot race the thread closing it (a traceback after Ctrl-C)."""
    import concurrent.futures as cf
    import concurrent.futures.process as cfp
    import multiprocessing as mp

    executor = cf.ProcessPoolExecutor(2, mp_context=mp.get_context("fork"))
    busy = [executor.submit(time.sleep, 60.0) for _ in range(2)]
    waiting = executor.submit(time.sleep, 60.0)
    deadline = time.monotonic() + 30.0
    while not all(f.running() for f in busy) and time.monotonic() < deadline:
        time.sleep(0.01)
    workers = list(executor._processes.values())
    manager = executor._executor_manager_thread
    wakeup = cfp._threads_wakeups[manager]
    start = time.monotonic()
    cp.stop_executor(executor)
    assert time.monotonic() - start < cp.EXECUTOR_STOP_TIMEOUT_S, "the busy workers were waited for, not killed"
    assert not manager.is_alive() and wakeup._closed
    assert waiting.done() and (waiting.cancelled() or waiting.exception() is not None), "a waiting run still ran"
    for proc in workers:
        proc.join(5.0)
        assert proc.exitcode is not None and proc.exitcode < 0, "a worker outlived the stop"
