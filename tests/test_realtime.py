"""The real-time module (:mod:`omnirotor.realtime`) shared by the flight node, the simulator and the PX4 bridge:
refusals said in one line each (the caller runs on), the collector held for a loop and given back, the options
checked alike by the three commands."""

from __future__ import annotations

import gc
import os

import pytest

from omnirotor import realtime
from omnirotor.cli import main


def test_refused_affinity_and_fifo_are_said_once_each_and_the_caller_runs_on(monkeypatch):
    def refuse(*_):
        raise PermissionError(1, "Operation not permitted")

    asked = []
    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    monkeypatch.setattr(os, "sched_setaffinity", lambda pid, cpus: asked.append(cpus) or refuse())
    said: list[str] = []
    realtime.set_realtime(1, 40, said.append)
    assert asked == [{1}]
    assert len(said) == 2
    assert said[0] == "CPU affinity to CPU 1 not permitted (PermissionError): the OS schedules the loop"
    assert said[1].startswith("SCHED_FIFO not permitted (needs CAP_SYS_NICE or an rtprio limit): the loop runs at")


def test_nothing_asked_nothing_said(monkeypatch):
    def forbidden(*_):
        raise AssertionError("asked the OS")

    monkeypatch.setattr(os, "sched_setscheduler", forbidden)
    monkeypatch.setattr(os, "sched_setaffinity", forbidden)
    said: list[str] = []
    realtime.set_realtime(None, None, said.append)
    assert said == []


def test_transport_priority_goes_to_every_other_thread_not_the_callers(monkeypatch):
    import threading

    asked: list[tuple[int, int, int]] = []
    monkeypatch.setattr(os, "sched_setscheduler", lambda tid, pol, p: asked.append((tid, pol, p.sched_priority)))
    ready, done = threading.Event(), threading.Event()
    other = threading.Thread(target=lambda: (ready.set(), done.wait(5.0)))
    other.start()
    ready.wait(5.0)
    try:
        said: list[str] = []
        n = realtime.set_transport_priority(10, said.append)
    finally:
        done.set()
        other.join()
    tids = {tid for tid, _, _ in asked}
    assert other.native_id in tids and threading.get_native_id() not in tids
    assert all(pol == os.SCHED_FIFO and p == 10 for _, pol, p in asked) and n == len(asked) and said == []


def test_transport_priority_refused_is_said_once_and_a_thread_that_ended_is_passed_over(monkeypatch):
    calls = []

    def refuse(tid, *_):
        calls.append(tid)
        if len(calls) == 1:
            raise ProcessLookupError(3, "No such process")  # ended between the listing and the call
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "listdir", lambda _: ["1", "2", "3", str(threading_id())])
    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    said: list[str] = []
    assert realtime.set_transport_priority(10, said.append) == 0
    assert calls == [1, 2]  # the refusal stops the round: said once, not per thread
    assert said == ["SCHED_FIFO for the transport's threads not permitted (needs CAP_SYS_NICE or an rtprio limit): "
                    "they run at normal priority"]  # fmt: skip
    assert realtime.set_transport_priority(None, said.append) == 0 and len(calls) == 2  # not asked: nothing done


def threading_id() -> int:
    import threading

    return threading.get_native_id()


def test_the_collector_is_held_for_the_block_and_given_back_however_it_ends():
    assert gc.isenabled()
    frozen0 = gc.get_freeze_count()
    with pytest.raises(KeyError), realtime.frozen_gc():
        assert not gc.isenabled() and gc.get_freeze_count() > frozen0
        raise KeyError
    assert gc.isenabled() and gc.get_freeze_count() == 0


@pytest.mark.parametrize(
    "argv",
    [
        ["px4-bridge", "--cpu", "4096"],
        ["px4-bridge", "--cpu", "-1"],
        ["px4-bridge", "--fifo-priority", "100"],
        ["sim", "--serve", "--task", "hover", "--cpu", "4096"],
        ["sim", "--serve", "--scene", "free", "--cpu", "-1"],
        ["fly", "--cpu", "4096"],
    ],
)
def test_real_time_options_out_of_range_are_one_line_and_exit_2_before_connecting(argv, capsys):
    assert main([*argv, "--connect", "tcp/127.0.0.1:1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    option = argv[argv.index("--cpu") if "--cpu" in argv else argv.index("--fifo-priority")]
    assert len(err) == 1 and f"{option} must be in 0.." in err[0], err
