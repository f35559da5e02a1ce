"""Campaigns under signals and against each other (issue 14): Ctrl-C, a killed main process, a second campaign.

The campaigns run in a subprocess of their own session, like a command typed in a terminal; every wait is
bounded, and the test kills what it started if anything overruns.

A command typed in a terminal takes Ctrl-C; one started in the background by a shell without job control
(``pytest ... &`` in a script, ``nohup``) ignores SIGINT, and so do its children, Python included (it installs
its KeyboardInterrupt handler only where SIGINT is not ignored). The suite run that way once saw the campaign
ignore the test's Ctrl-C and finish its runs (exit 0). The subprocess therefore takes SIGINT as a terminal's
command does (:data:`TERMINAL_SIGINT`), and the test checks that it does before signalling.
"""

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from omnirotor.cli import main
from omnirotor.experiments.campaigns import runner as campaign_mod
from omnirotor.experiments.campaigns.runner import execute_run, load_campaign, run_campaign, run_options
from test_campaign import tiny

SRC = str(Path(__file__).resolve().parents[1] / "src")
START_TIMEOUT_S = 300  # the first run may compile the kernels
EXIT_TIMEOUT_S = 60


# Far more runs than can finish before the signal, even when this process is starved: the campaign runs in a
# session of its own, which the kernel's autogroup scheduling gives a CPU share of its own, so under load it
# can run at full speed while this process waits. 200 runs (about 7 s on 2 cores) could finish first in the
# full suite under load (the campaign then exited 0 before the Ctrl-C); 1000 take about 35 s. (With 3000 queued, one
# loaded run took over 60 s to exit after the Ctrl-C: cancelling thousands of queued futures is slow; not examined.)
MANY_RUNS = "1000"


TERMINAL_SIGINT = "import signal; signal.signal(signal.SIGINT, signal.default_int_handler)"
"""Ctrl-C raises KeyboardInterrupt, as in a command typed in a terminal, whatever this process ignores."""


def campaign_argv(tmp_path, out, *extra):
    """The command line of a campaign of the tiny test campaign file in a subprocess, and its environment."""
    env = {**os.environ, "PYTHONPATH": SRC + os.pathsep + os.environ.get("PYTHONPATH", "")}
    argv = [sys.executable, "-c", f"{TERMINAL_SIGINT}; from omnirotor.cli import main; main()", "campaign",
            "--campaign", str(tiny(tmp_path)), "--runs", MANY_RUNS, "--out", str(out), *extra]  # fmt: skip
    return argv, env


def catches_sigint(pid):
    """True when process ``pid`` has a handler of its own for SIGINT (neither ignored nor the default action)."""
    status = Path(f"/proc/{pid}/status").read_text()
    caught = int(next(x for x in status.splitlines() if x.startswith("SigCgt:")).split()[1], 16)
    return bool(caught & (1 << (signal.SIGINT - 1)))


def start(tmp_path, out, workers=2):
    argv, env = campaign_argv(tmp_path, out, "--workers", str(workers))
    return subprocess.Popen(
        argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, start_new_session=True
    )


def children(pid):
    """Pids whose parent is ``pid``."""
    out = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            with contextlib.suppress(OSError, IndexError):
                stat = Path(f"/proc/{entry}/stat").read_text()
                if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                    out.append(int(entry))
    return out


def alive(pid):
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def wait_for(cond, timeout, proc=None):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if cond():
            return True
        if proc is not None and proc.poll() is not None:
            return cond()
        time.sleep(0.2)
    return False


def finished_lines(out):
    p = out / "results.jsonl"
    return [x for x in p.read_text().split("\n")[:-1]] if p.exists() else []


@pytest.fixture
def cleanup():
    procs = []
    yield procs
    for p in procs:
        for pid in [p.pid, *children(p.pid)] if p.poll() is None else []:
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)
        with contextlib.suppress(Exception):
            p.communicate(timeout=10)


def running_campaign(tmp_path, out, cleanup):
    """A campaign with two workers in a subprocess, once its first run is saved; returns it and its workers."""
    proc = start(tmp_path, out)
    cleanup.append(proc)
    assert wait_for(lambda: len(finished_lines(out)) >= 1, START_TIMEOUT_S, proc), proc.poll()
    workers = children(proc.pid)
    assert len(workers) >= 2
    return proc, workers


@pytest.mark.slow
def test_ctrl_c_exits_130_keeps_results_and_a_second_campaign_is_refused(tmp_path, capsys, cleanup):
    out = tmp_path / "c"
    proc, workers = running_campaign(tmp_path, out, cleanup)
    # a second campaign into the same folder is refused while the first runs, and changes nothing
    before = (out / "campaign.json").read_bytes()
    code = main(
        ["campaign", "--campaign", str(tiny(tmp_path)), "--runs", MANY_RUNS, "--workers", "1", "--out", str(out)]
    )
    err = capsys.readouterr().err
    assert code == 2 and "another campaign" in err and len(err.strip().splitlines()) == 1
    assert (out / "campaign.json").read_bytes() == before
    assert catches_sigint(proc.pid), "the campaign ignores SIGINT: it could not be stopped by a Ctrl-C"
    assert len(finished_lines(out)) < int(MANY_RUNS) and proc.poll() is None, "the campaign ended before the Ctrl-C"
    os.killpg(proc.pid, signal.SIGINT)  # Ctrl-C in a terminal reaches the whole process group
    _, stderr = proc.communicate(timeout=EXIT_TIMEOUT_S)
    assert proc.returncode == 130
    lines = [x for x in stderr.strip().splitlines() if x.strip()]
    assert len(lines) == 1 and lines[0].startswith("omnirotor: interrupted"), stderr
    done = [json.loads(x) for x in finished_lines(out)]  # every line complete and valid
    assert len(done) >= 1 and len({r["index"] for r in done}) == len(done)
    assert wait_for(lambda: not any(alive(w) for w in workers), 10)


@pytest.mark.slow
def test_workers_die_with_a_killed_main_process_and_the_campaign_resumes(tmp_path, cleanup):
    out = tmp_path / "c"
    proc, workers = running_campaign(tmp_path, out, cleanup)
    os.kill(proc.pid, signal.SIGKILL)
    proc.communicate(timeout=EXIT_TIMEOUT_S)
    assert wait_for(lambda: not any(alive(w) for w in workers), 10), "pool workers outlived the main process"
    # the lock died with its holder: the campaign resumes, and each index is run exactly once
    n_before = len({json.loads(x)["index"] for x in finished_lines(out)})
    spec = load_campaign(tiny(tmp_path))
    s = run_campaign(spec, out, runs=n_before + 1, workers=1, plots=False)
    assert s["runs_done"] == n_before + 1
    idx = [json.loads(x)["index"] for x in finished_lines(out)]
    assert len(idx) == len(set(idx)) and set(range(n_before + 1)) <= set(idx)


def fake_task(monkeypatch, summary):
    """Replace the closed-loop task by one that returns ``summary`` at once."""
    from omnirotor.experiments import tasks

    class Result:
        def summary(self):
            return dict(summary)

    monkeypatch.setattr(tasks, "run_task", lambda task, options, progress=None: Result())


def test_a_run_with_non_finite_steps_is_a_failure_with_its_cause(tmp_path, monkeypatch):
    fake_task(monkeypatch, {"success": True, "ee_rms_error": {"x_cm": float("nan"), "y_cm": 1.0}, "duration_s": 0.3})
    rec = execute_run(run_options(load_campaign(tiny(tmp_path)), 0))
    assert rec["status"] == "ok" and rec["success"] is False
    assert "ee_rms_error.x_cm" in rec["failure"]
    assert rec["metrics"]["ee_rms_error"]["x_cm"] is None  # stored as null, never bare NaN


def test_a_plotting_failure_keeps_the_summary(tmp_path, monkeypatch, capsys):
    def broken_plots(*args, **kwargs):
        raise RuntimeError("no display")

    fake_task(monkeypatch, {"success": True, "ee_rms_error": {"x_cm": 1.0}, "duration_s": 0.3})
    monkeypatch.setattr(campaign_mod, "plot_campaign", broken_plots)
    out = tmp_path / "c"
    s = run_campaign(load_campaign(tiny(tmp_path)), out, runs=2, workers=1)
    stored = json.loads((out / "summary.json").read_text())
    assert stored["runs_done"] == 2 and stored["successes"] == 2
    assert "no display" in stored["plots_error"] and s["plots_error"] == stored["plots_error"]
    assert "plots failed" in capsys.readouterr().err
