"""The flight node's loop (``omnirotor.fly.node.NodeLoop``) against a scripted plant over real Zenoh on loopback."""

from __future__ import annotations

import contextlib
import threading
import time
import types

import numpy as np
import pytest

from omnirotor.fly.node import _LATENCY_WINDOW, LoopStats, NodeLoop, NodeOptions
from omnirotor.messages import ControlStatus, RotorCommand, new_frame
from omnirotor.rosmsg.convert import COMMAND, CONTROLLER_LOG, FRAME, WireMessages
from omnirotor.transport import open_transport
from sitl.procs import free_port

N = 8
PLANT = 0x5107A7E000000001
"""The scripted plant's session (``SensorFrame.session_id``)."""


class _Controller:
    """Steps count; the command is the frame's time as every rotor's speed."""

    def __init__(self) -> None:
        self.vehicle = types.SimpleNamespace(n_rotors=N)
        self.steps = 0

    def step(self, frame) -> RotorCommand:
        self.steps += 1
        return RotorCommand(frame.t, np.full(N, 100.0 + 1000.0 * frame.t), ControlStatus.OK)


class _Director:
    def __init__(self) -> None:
        self.frames = []
        self.stopped = False
        self._out = np.zeros(N)

    def on_frame(self, frame, ages) -> None:
        if ages.frames_stopped:
            self.stopped = True
        elif ages.imu_age_s == 0.0:  # a frame (between frames the node calls with the growing link age)
            self.frames.append(float(frame.t))

    def wants_step(self) -> bool:
        return True

    def output(self, cmd) -> np.ndarray:
        self._out[:] = cmd.omega_hz if cmd is not None else 0.0
        return self._out


class _Plant:
    """The scripted plant's side: the test's Zenoh session (listening) with the frame publisher and the command
    subscriber, one frame record and its message; the node's summary once its loop ended."""

    def __init__(self, plant, node: NodeLoop) -> None:
        self.plant, self.node = plant, node
        self.frames = plant.publisher("/omnirotor/frame", FRAME, block=True)
        self.commands = plant.subscriber("/omnirotor/rotor_cmd", COMMAND, depth=64)
        self.record, self._msgs = new_frame(N), WireMessages(N)
        self._msgs.frame.session_id = PLANT
        self.summary: dict = {}
        self.thread: threading.Thread | None = None

    def send(self, seq: int, t: float | None = None, session: int = PLANT) -> None:
        """Publish the record as frame ``seq`` of plant ``session`` (its time set to ``t`` first, when given)."""
        if t is not None:
            self.record["t"] = t
        self._msgs.frame.session_id = session
        self.frames.put(self._msgs.fill_frame(self.record, seq))

    def answers(self, timeout_s: float) -> list:
        """The commands that arrived, the first waited for up to ``timeout_s``."""
        return list(iter(lambda: self.commands.take(timeout_s), None))

    def stream(self, n_answers: int, wait_s: float, timeout_s: float, between=None) -> list:
        """Frames 1, 2, ... (1 ms apart in time), each followed by up to ``wait_s`` for answers and ``between(k)``,
        until ``n_answers`` commands came or ``timeout_s`` passed; the commands."""
        got, k = [], 0
        deadline = time.monotonic() + timeout_s
        while len(got) < n_answers and time.monotonic() < deadline:
            k += 1
            self.send(k, 0.001 * k)
            got += self.answers(wait_s)
            if between is not None:
                between(k)
        return got


@contextlib.contextmanager
def _scripted_plant(namespace: str, controller, director, options: NodeOptions, say=None):
    """A :class:`_Plant` on loopback Zenoh and the node's loop on its own session, run in a thread until the block
    ends (then stopped and joined)."""
    port = free_port()
    with (
        open_transport(listen=[f"tcp/127.0.0.1:{port}"], namespace=namespace) as plant,
        open_transport(listen=[], connect=[f"tcp/127.0.0.1:{port}"], namespace=namespace) as wire,
    ):
        node = NodeLoop(wire, controller, director, options, say=say if say is not None else (lambda line: None))
        p = _Plant(plant, node)
        stop = threading.Event()
        p.thread = threading.Thread(target=lambda: p.summary.update(node.run(stop)))
        p.thread.start()
        try:
            yield p
        finally:
            stop.set()
            p.thread.join(10)


def test_a_repeated_start_frame_is_answered_again_and_keeps_the_link():
    """The simulator repeats its start frame every 10 ms until it obeys an answer: no link loss, nothing stepped."""
    ctl, director = _Controller(), _Director()
    said: list[str] = []
    with _scripted_plant("/node", ctl, director, NodeOptions(), said.append) as p:
        answers = []
        deadline = time.monotonic() + 10
        while not answers and time.monotonic() < deadline:  # the subscription takes a moment to match
            p.send(0, 0.5)
            answers += p.answers(0.01)
        for _ in range(6):  # the start frame again, 20 ms apart, for longer than the 50 ms link loss
            time.sleep(0.02)
            p.send(0)
        time.sleep(0.02)
        p.send(1, 0.501)
        deadline = time.monotonic() + 5
        while (not answers or answers[-1].frame_seq != 1) and time.monotonic() < deadline:
            if (m := p.commands.take(0.01)) is not None:
                answers.append(m)
        lost = [line for line in said if "link lost" in line]  # before the frames stop here
    summary = p.summary
    assert lost == [], said
    assert ctl.steps == 2 and director.frames == [0.5, 0.501]  # the repeats stepped nothing
    seqs = [int(m.seq) for m in answers]
    assert seqs == sorted(set(seqs)) and len(answers) >= 5  # every answer a new sequence number
    assert [int(m.frame_seq) for m in answers[:-1]] == [0] * (len(answers) - 1) and answers[-1].frame_seq == 1
    assert all(np.array_equal(m.hz, answers[0].hz) for m in answers[:-1])  # the same answer again
    assert np.allclose(answers[-1].hz, 100.0 + 501.0)
    assert summary["start_frame_answered_again"] >= len(answers) - 2


def test_the_status_p99_is_of_the_recent_periods_across_the_window_wrap():
    """The status's percentile looks at the last 1000 frames only (the whole window took milliseconds)."""

    s = LoopStats(0.0005)
    assert s.recent_p99_s() == 0.0
    for k in range(_LATENCY_WINDOW + 500):  # wraps the window: the last 1000 straddle its end
        s.period(1e-3 if k < _LATENCY_WINDOW - 500 else 1e-4, 0.0, 0.0, 1e-3)
    assert s.recent_p99_s() == pytest.approx(1e-4)
    s.period(5e-3, 0.0, 0.0, 1e-3)
    assert s.recent_p99_s() == pytest.approx(np.percentile([1e-4] * 999 + [5e-3], 99))


def test_the_status_p99_is_the_nearest_rank_of_the_recent_periods():
    """The ceil(0.99 n)-th smallest of the last n <= 1000 latencies, whatever their order; the window is untouched."""
    rng = np.random.default_rng(7)
    for n in (1, 7, 100, 999, 1000, 1500):
        s = LoopStats(0.0005)
        x = rng.permutation(np.arange(1, n + 1) * 1e-6)
        for v in x:
            s.period(float(v), 0.0, 0.0, 1e-3)
        recent = x[-1000:]
        expected = np.sort(recent)[int(np.ceil(0.99 * recent.size)) - 1]
        assert s.recent_p99_s() == expected
        assert np.array_equal(s._latency[: min(n, _LATENCY_WINDOW)], x[: min(n, _LATENCY_WINDOW)])  # order kept


class _SlowDirector(_Director):
    """Records each frame's motion capture; on the first frame it holds the loop until told (frames queue up)."""

    def __init__(self) -> None:
        super().__init__()
        self.mocap = []
        self.busy = threading.Event()
        self.release = threading.Event()

    def on_frame(self, frame, ages) -> None:
        super().on_frame(frame, ages)
        if ages.imu_age_s == 0.0 and not ages.frames_stopped:
            self.mocap.append((float(frame.t), frame.mocap_new, None if not frame.mocap_new else
                               (float(frame.mocap_t), tuple(frame.mocap_p_W))))  # fmt: skip
            if len(self.mocap) == 1:
                self.busy.set()
                self.release.wait(10)


def test_a_motion_capture_sample_in_a_skipped_frame_is_not_lost():
    """A loop that fell behind takes the newest frame; the motion-capture sample of a frame it skipped rides with it.

    Before: the node took the newest frame only, so under load the motion-capture samples (one frame in ten) were
    dropped with the frames skipped and the estimate ran on the IMU alone.
    """
    director = _SlowDirector()
    with _scripted_plant("/skip", _Controller(), director, NodeOptions(lockstep=True)) as p:

        def send(k: int, mocap: bool) -> None:
            m = p.record["mocap"]
            m["new"] = mocap
            m["t"] = 0.001 * k - 0.0005 if mocap else 0.0
            m["p_W"] = (k, 2.0, 3.0)
            m["q_WB"] = (1.0, 0.0, 0.0, 0.0)
            p.send(k, 0.001 * k)

        deadline = time.monotonic() + 10
        while not director.busy.is_set() and time.monotonic() < deadline:  # matching takes a moment
            send(1, False)
            time.sleep(0.02)
        assert director.busy.is_set()
        send(2, True)  # the loop is busy: these queue up
        send(3, False)
        send(4, False)
        time.sleep(0.5)
        director.release.set()
        deadline = time.monotonic() + 5
        while len(director.mocap) < 2 and time.monotonic() < deadline:
            time.sleep(0.01)
    summary = p.summary
    first, newest = director.mocap[0], director.mocap[1]
    assert first[:2] == (0.001, False)
    assert newest == (0.004, True, (0.0015, (2.0, 2.0, 3.0)))  # frame 4, with frame 2's sample
    assert summary["mocap_carried"] == 1


class _DisarmedButSpinning(_Director):
    """A wrong director: disarmed, yet it outputs speeds."""

    armed = False

    def output(self, cmd) -> np.ndarray:
        self._out[:] = 300.0
        return self._out


def test_a_disarmed_director_never_gets_speeds_published():
    """The node's invariant: while the director is disarmed only zeros go out, flagged STATE_STOP."""
    from omnirotor.rosmsg.convert import COMMAND_STOP

    with _scripted_plant("/inv", _Controller(), _DisarmedButSpinning(), NodeOptions(lockstep=True)) as p:
        answers = p.stream(5, 0.02, 10.0)
    summary = p.summary
    assert len(answers) >= 5
    assert all(not m.hz.any() and m.state == COMMAND_STOP for m in answers)
    assert summary["disarmed_nonzero"] >= 5


def _sim_status(**fields):
    """A healthy plant's ``SimStatus`` (the scripted plant's session), ``fields`` replaced."""
    from omnirotor.rosmsg import typestore
    from omnirotor.rosmsg.convert import SIM_STATUS

    T = typestore().types
    values = dict(
        header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id=""),
        t=0.0, steps=0, lockstep=False, failsafe=0, cause="", paired_session_id=0, commands_obeyed=0,
        commands_held=0, commands_refused=0, foreign_sessions=0, bad_payloads=0, command_age_s=0.0, finished=False,
        plant_session_id=PLANT, imu_rate_off_episodes=0, imu_rate_off_s=0.0, imu_gaps=0, imu_worst_gap_s=0.0,
    )  # fmt: skip
    values.update(fields)
    return T[SIM_STATUS](**values)


class _TellableDirector(_Director):
    def __init__(self) -> None:
        super().__init__()
        self.told = []

    def plant_failsafe(self, why: str) -> None:
        self.told.append(why)


def test_the_end_of_a_mission_is_not_taken_for_a_lost_link():
    """The plant's frames stop at the end of its run and its status says "finished"; the loop reads the status at
    its own rate (here every 2 s, as a starved loop might): the link's 50 ms timeout must not call the end a link
    loss (seen under load in test_sitl_fuzz)."""
    from omnirotor.rosmsg.convert import SIM_STATUS

    said: list[str] = []
    opts = NodeOptions(status_hz=0.5, log_rows=True)
    with _scripted_plant("/end", _LoggingController(), _Director(), opts, said.append) as p:
        status = p.plant.publisher("/omnirotor/sim_status", SIM_STATUS, block=True)
        got = p.stream(20, 0.01, 30.0)
        assert len(got) >= 20
        lost_before = sum("link lost" in line for line in said)  # (a pause of this process mid-stream may lose it)
        status.put(_sim_status(steps=max(int(m.frame_seq) for m in got), finished=True))  # as the simulator does
        p.thread.join(10)
        assert not p.thread.is_alive()  # the loop ended by itself
    assert sum("link lost" in line for line in said) == lost_before, said
    assert not p.summary["link_lost"]


@pytest.mark.parametrize("own", [PLANT, 0], ids=["the-plant-followed", "a-frameless-bridge"])
def test_the_plant_s_failsafe_is_told_to_the_director(own):
    """The simulator's offboard-loss failsafe (or PX4 out of offboard, from the bridge) in SimStatus: the director
    is told while it lasts, the node says it once; from the plant followed, or from a bridge that sends no frames
    (its status names no plant session)."""
    from omnirotor.rosmsg.convert import SIM_STATUS

    said: list[str] = []
    director = _TellableDirector()
    options = NodeOptions(status_hz=200.0, plant_session=PLANT)  # the status of the plant followed (pinned)
    with _scripted_plant("/told", _Controller(), director, options, said.append) as p:
        status = p.plant.publisher("/omnirotor/sim_status", SIM_STATUS, block=True)
        msg = _sim_status(plant_session_id=own)
        for _ in range(20):  # healthy: nothing told
            status.put(msg)
            time.sleep(0.01)
        assert director.told == []
        msg.failsafe, msg.cause = 1, "offboard loss"
        deadline = time.monotonic() + 10
        while len(director.told) < 3 and time.monotonic() < deadline:
            status.put(msg)
            time.sleep(0.01)
    assert len(director.told) >= 3 and set(director.told) == {"offboard loss"}
    assert [line for line in said if "stopped obeying" in line] == [
        "the plant stopped obeying the commands: offboard loss"
    ]


class _LoggingController(_Controller):
    """A controller with a log: each step writes the row (frame time, step count)."""

    def __init__(self) -> None:
        super().__init__()
        self.log = types.SimpleNamespace(data=np.zeros((100, 2)), n=0)

    def step(self, frame) -> RotorCommand:
        cmd = super().step(frame)
        self.log.data[self.log.n] = (frame.t, self.steps)
        self.log.n += 1
        return cmd


def test_a_status_of_another_plant_session_is_ignored_never_obeyed():
    """A ``SimStatus`` naming another plant session than the followed one (a second plant whose failsafe fired, or
    a forger), or naming none once the followed plant's own was heard, neither disarms the director nor ends the
    run: ignored, counted, the other session said once; the followed plant's own status still is (issue 26 item 5:
    only the paired plant is heeded)."""
    from omnirotor.rosmsg.convert import SIM_STATUS

    said: list[str] = []
    director = _TellableDirector()
    options = NodeOptions(lockstep=True, status_hz=200.0, log_rows=True)  # first come: the plant's frame first
    with _scripted_plant("/forged_status", _LoggingController(), director, options, said.append) as p:
        status = p.plant.publisher("/omnirotor/sim_status", SIM_STATUS, block=True)
        _until_answered(p, 1, 0.001)
        seq, deadline = 2, time.monotonic() + 10
        while p.node.plant_imu is None and time.monotonic() < deadline:  # the plant's own status heard once
            status.put(_sim_status())
            p.send(seq, 0.001 * seq)
            seq += 1
            time.sleep(0.005)
        # another plant's (or a forger's) failsafe and end; then one naming no plant (as a frameless bridge)
        forged = [
            _sim_status(plant_session_id=session, failsafe=1, cause="forged", finished=True, steps=0)
            for session in (FOREIGN, 0)
        ]
        deadline = time.monotonic() + 10
        while getattr(p.node, "statuses_foreign", 0) < 20 and not director.told and time.monotonic() < deadline:
            status.put(forged[seq % 2])
            p.send(seq, 0.001 * seq)  # frames keep the loop turning (it reads the status between frames)
            seq += 1
            time.sleep(0.005)
        assert director.told == [] and not p.node.finished  # neither obeyed
        assert p.node.statuses_foreign >= 20
        own = _sim_status(failsafe=1, cause="offboard loss")
        deadline = time.monotonic() + 10
        while not director.told and time.monotonic() < deadline:
            status.put(own)
            p.send(seq, 0.001 * seq)
            seq += 1
            time.sleep(0.005)
    assert set(director.told) == {"offboard loss"}  # the followed plant's own failsafe still disarms
    assert p.summary["plant_statuses_foreign"] >= 20
    assert [line for line in said if "status names" in line] == [
        f"the plant's status names plant session {FOREIGN:016x}, not the followed {PLANT:016x}: its frames and its "
        f"status are ignored (follow it: --plant-session {FOREIGN:016x})"
    ]


def test_a_lockstep_node_sends_its_last_rows_when_the_frames_pause():
    """A mission's last partial batch of log rows goes when the plant stops sending frames, even when the plant's
    "finished" status never arrives (it did not on a loaded machine: the simulator then filled 17 rows in)."""
    got: dict[int, np.ndarray] = {}
    with _scripted_plant("/node", _LoggingController(), _Director(), NodeOptions(lockstep=True, log_rows=True)) as p:
        rows = p.plant.subscriber("/omnirotor/controller_log", CONTROLLER_LOG, depth=64)
        for seq in range(1, 8):  # each frame answered before the next, as a lockstep plant does
            answered = False
            deadline = time.monotonic() + 10
            while not answered and time.monotonic() < deadline:
                p.send(seq, 0.001 * seq)
                answered = any(int(m.frame_seq) == seq for m in p.answers(0.05))
            assert answered, seq
        deadline = time.monotonic() + 5  # then no frame: a lockstep plant whose run ended
        while len(got) < 7 and time.monotonic() < deadline:
            if (m := rows.take(0.05)) is not None:
                k = int(m.n_columns)
                for seq, row in zip(m.frame_seq, np.asarray(m.rows).reshape(-1, k), strict=True):
                    got[int(seq)] = row
    assert sorted(got) == list(range(1, 8))
    assert [float(got[s][0]) for s in range(1, 8)] == pytest.approx([0.001 * s for s in range(1, 8)])


class _ThreadRecordingDirector(_Director):
    """Records the thread of every call; answers requests (``omnirotor ctl``) with a dict of FlightReply's fields."""

    def __init__(self) -> None:
        super().__init__()
        self.threads: set[int] = set()
        self.requests = 0
        self.gap_calls = 0

    def on_frame(self, frame, ages) -> None:
        self.threads.add(threading.get_ident())
        if not ages.frames_stopped and ages.imu_age_s > 0.0:
            self.gap_calls += 1
        super().on_frame(frame, ages)

    def wants_step(self) -> bool:
        self.threads.add(threading.get_ident())
        return True

    def output(self, cmd) -> np.ndarray:
        self.threads.add(threading.get_ident())
        return super().output(cmd)

    def request(self, req):
        self.threads.add(threading.get_ident())
        self.requests += 1
        return {"accepted": True, "kind": int(req.kind), "mode_from": 0, "mode": 0, "message": "ok"}


def test_the_director_is_only_ever_called_from_the_loop_s_thread():
    """Frames, the gap calls when they stop, the link loss and ``ctl`` requests (answered over Zenoh): every call
    of the director on the loop's one thread (it is not thread-safe), whatever thread the transport receives on."""
    from omnirotor.rosmsg import typestore
    from omnirotor.sitl.server import TOPICS

    T = typestore().types
    director = _ThreadRecordingDirector()
    replies = []
    req = T["omnirotor_msgs/msg/FlightRequest"](
        kind=0, height_m=0.0, depth_m=0.0, name="", force=False,
        setpoint=T["omnirotor_msgs/msg/Setpoint"](
            p_w=np.zeros(3), q_wb=np.zeros(4), roll_deg=0.0, pitch_deg=0.0, yaw_deg=0.0, duration_s=0.0
        ),
    )  # fmt: skip
    with _scripted_plant("/thr", _Controller(), director, NodeOptions(wrench_every=10**9)) as p:

        def ask(k: int) -> None:  # a request from a client while frames flow
            if k % 10 == 0:
                replies.append(p.plant.request(TOPICS["ctl"], "omnirotor_msgs/msg/FlightRequest", req,
                                               "omnirotor_msgs/msg/FlightReply", 2.0))  # fmt: skip

        answers = p.stream(50, 0.005, 20.0, ask)
        # frames stop: gap calls, then the link loss
        assert wait_until_true(lambda: director.stopped, 10.0)
    loop_thread = p.thread
    assert len(answers) >= 50 and director.gap_calls > 0 and director.stopped and director.requests > 0
    assert any(r is not None and r.accepted for r in replies)
    assert director.threads == {loop_thread.ident}


def wait_until_true(fn, timeout_s: float) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if fn():
            return True
        time.sleep(0.005)
    return False


# -- the plant the node follows (omnirotor.sitl.gate.FrameGate; issue 26 item 5) -----------------------------------

FOREIGN = 0x0BAD5E55F7A3E001
"""Another plant session: a flooder's forged frames, or a second plant."""


def _until_answered(p: _Plant, seq: int, t: float, timeout_s: float = 10.0, session: int = PLANT) -> list:
    """Frame ``seq`` of ``session`` sent every 20 ms until a command answers it (the subscription takes a moment to
    match); the commands that came meanwhile."""
    got: list = []
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        p.send(seq, t, session)
        got += p.answers(0.02)
        if any(int(m.frame_seq) == seq for m in got):
            return got
    raise AssertionError(f"frame {seq} of {session:016x} was never answered")


def _foreign_until_refused(p: _Plant, n: int, first_seq: int = 1) -> int:
    """Foreign frames numbered from ``first_seq`` until the node refused ``n`` of them; the next number."""
    seq, deadline = first_seq, time.monotonic() + 10
    while p.node.plant_gate.refused_foreign < n and time.monotonic() < deadline:
        p.send(seq, 0.001 * seq, FOREIGN)
        seq += 1
        time.sleep(0.002)
    assert p.node.plant_gate.refused_foreign >= n
    return seq


def test_a_pinned_node_follows_its_plant_through_foreign_frames_that_came_first():
    """``--plant-session``: a flood of well-formed frames of another session with plausible numbers, before and
    between the plant's, is refused from the very first, counted apart from the bad ones, said once; never
    followed, never answered, never stepped."""
    ctl, director = _Controller(), _Director()
    said: list[str] = []
    with _scripted_plant(
        "/pin", ctl, director, NodeOptions(lockstep=True, plant_session=PLANT, wrench_every=10**6), said.append
    ) as p:
        seq = _foreign_until_refused(p, 20)  # before the plant's first frame
        assert p.answers(0.05) == [] and ctl.steps == 0
        answers = _until_answered(p, 1, 0.001)
        for k in range(2, 30):
            p.send(seq, 0.5, FOREIGN)  # a forged frame one ahead of the plant's next, then the plant's own
            seq += 1
            p.send(k, 0.001 * k)
            answers += p.answers(0.05)
        deadline = time.monotonic() + 10  # the plant's last frame answered (a loaded machine may skip some before)
        while 29 not in {int(m.frame_seq) for m in answers} and time.monotonic() < deadline:
            answers += p.answers(0.05)
    s = p.summary
    assert 29 in {int(m.frame_seq) for m in answers}
    # only the plant's frames were flown (the forged ones are at 0.5 s), the last one among them
    assert all(t < 0.5 for t in director.frames) and 0.029 in director.frames and ctl.steps == len(director.frames)
    assert s["plant_session_id"] == f"{PLANT:016x}" and s["plant_session_pinned"]
    # those before the plant's first frame at least (a frame queued behind a newer one taken is skipped unread)
    assert s["frames_foreign"] >= 20 and s["foreign_plant_sessions"] == 1
    assert s["frames_bad"] == 0  # the foreign frames are not counted as malformed
    refused = [line for line in said if "refused sensor frames" in line]
    assert refused == [
        f"refused sensor frames of plant session {FOREIGN:016x}: following {PLANT:016x} (--plant-session)"
    ]
    assert f"the pinned plant session {PLANT:016x} sends frames" in said
    assert not any("following plant session" in line for line in said)  # never first come


def test_a_first_come_node_follows_whoever_sends_first_and_says_so():
    """Without ``--plant-session`` the first well-formed frame's session is followed (documented), the later plant
    is refused and named, and the plant's status naming its own session makes the node say how to pin it."""
    from omnirotor.rosmsg.convert import SIM_STATUS

    ctl, director = _Controller(), _Director()
    said: list[str] = []
    with _scripted_plant("/first", ctl, director, NodeOptions(lockstep=True, status_hz=200.0), said.append) as p:
        _until_answered(p, 1, 0.001, session=FOREIGN)  # the flooder comes first
        _until_answered(p, 2, 0.002, session=FOREIGN)
        for k in range(1, 10):  # the real plant's frames: refused
            p.send(k, 0.1 + 0.001 * k)
        assert p.answers(0.2) == []  # none of the real plant's frames is answered
        status = p.plant.publisher("/omnirotor/sim_status", SIM_STATUS, block=True)
        msg = _sim_status(lockstep=True)
        deadline = time.monotonic() + 10
        while not any("status names" in line for line in said) and time.monotonic() < deadline:
            status.put(msg)
            p.send(3, 0.003, FOREIGN)  # frames keep the loop turning (it reads the status between frames)
            time.sleep(0.01)
    s = p.summary
    assert s["plant_session_id"] == f"{FOREIGN:016x}" and not s["plant_session_pinned"]
    assert s["frames_foreign"] >= 1 and s["foreign_plant_sessions"] == 1
    assert all(t < 0.1 for t in director.frames)  # only the first come's frames were flown
    assert (
        f"following plant session {FOREIGN:016x}, the first to send frames (first come: --plant-session pins one)"
        in said
    )
    assert f"refused sensor frames of plant session {PLANT:016x}: following {FOREIGN:016x}" in said
    assert (
        f"the plant's status names plant session {PLANT:016x}, not the followed {FOREIGN:016x}: its frames and "
        f"its status are ignored (follow it: --plant-session {PLANT:016x})"
    ) in said


class _ArmedDirector(_Director):
    armed = True


@pytest.mark.parametrize(
    "pinned, armed, released",
    [(None, False, True), (None, True, False), (PLANT, False, False)],
    ids=["first-come-disarmed", "first-come-armed", "pinned"],
)
def test_a_link_loss_releases_only_a_first_come_plant_of_a_disarmed_node(pinned, armed, released):
    """After a link loss the followed plant's numbers start anew (any number); another plant is followed only when
    the pairing was first come and the director is disarmed (never in flight, never pinned)."""
    ctl, director = _Controller(), (_ArmedDirector() if armed else _Director())
    said: list[str] = []
    options = NodeOptions(lockstep=True, lockstep_link_loss_s=0.2, plant_session=pinned)
    with _scripted_plant("/loss", ctl, director, options, said.append) as p:
        _until_answered(p, 1, 0.001)
        _until_answered(p, 2, 0.002)
        deadline = time.monotonic() + 10
        while not any("link lost" in line for line in said) and time.monotonic() < deadline:
            time.sleep(0.01)
        assert any("link lost" in line for line in said), said
        if released:
            answers = _until_answered(p, 7, 0.5, session=FOREIGN)  # the next plant to send frames is followed
        else:
            for _ in range(10):
                p.send(7, 0.5, FOREIGN)
                time.sleep(0.01)
            assert [m for m in p.answers(0.2) if int(m.frame_seq) == 7] == []  # refused
            answers = _until_answered(p, 5000, 0.6)  # the same plant, its count far on: followed
    s = p.summary
    assert answers
    gone = f"plant session {PLANT:016x} released (link lost, disarmed)"
    if released:
        assert any(gone in line for line in said) and s["plant_session_id"] == f"{FOREIGN:016x}"
        assert 0.5 in director.frames
    else:
        assert not any(gone in line for line in said) and s["plant_session_id"] == f"{PLANT:016x}"
        assert 0.6 in director.frames and 0.5 not in director.frames and s["frames_foreign"] >= 1


def test_frames_without_a_plant_session_are_refused_and_never_paired_with():
    """A frame with ``session_id`` 0 (a plant that does not say who it is) is bad, said once; a first-come node
    does not pair with it and follows the first plant that says its session."""
    ctl, director = _Controller(), _Director()
    said: list[str] = []
    with _scripted_plant("/unsigned", ctl, director, NodeOptions(lockstep=True), said.append) as p:
        deadline = time.monotonic() + 10
        while p.node.frames_unsigned < 5 and time.monotonic() < deadline:
            p.send(1, 0.001, 0)
            time.sleep(0.01)
        assert p.answers(0.1) == [] and p.node.plant_gate.paired == 0
        _until_answered(p, 2, 0.002)
    s = p.summary
    assert s["plant_session_id"] == f"{PLANT:016x}" and s["frames_bad"] >= 5 and s["frames_foreign"] == 0
    assert director.frames == [0.002]
    assert [line for line in said if "without a plant session" in line] == [
        "refused sensor frames without a plant session (session_id 0): a plant fills it"
    ]


class _StatusDirector(_Director):
    """Answers ``omnirotor ctl status`` as the flight director does (a FlightReply)."""

    def request(self, req):
        from omnirotor.fly.modes import FlightMode
        from omnirotor.fly.requests import FlightReply

        return FlightReply(True, "status", FlightMode.DISARMED, FlightMode.DISARMED, "mode disarmed")


def test_ctl_status_names_the_plant_followed_and_what_was_refused():
    """``omnirotor ctl status`` shows what diagnoses a pairing: the plant session followed and how, the frames of
    other sessions refused and how many sessions, the node's own session."""
    import re

    from omnirotor.fly.requests import REQUEST_IDS
    from omnirotor.rosmsg import typestore
    from omnirotor.sitl.server import TOPICS

    T = typestore().types
    req = T["omnirotor_msgs/msg/FlightRequest"](
        kind=REQUEST_IDS["status"], height_m=0.0, depth_m=0.0, name="", force=False,
        setpoint=T["omnirotor_msgs/msg/Setpoint"](
            p_w=np.zeros(3), q_wb=np.zeros(4), roll_deg=0.0, pitch_deg=0.0, yaw_deg=0.0, duration_s=0.0
        ),
    )  # fmt: skip
    options = NodeOptions(lockstep=True, plant_session=PLANT, session_id=0x1A2B3C4D5E6F7081)
    with _scripted_plant("/ctl_status", _Controller(), _StatusDirector(), options) as p:
        _foreign_until_refused(p, 5)
        _until_answered(p, 1, 0.001)
        reply = p.plant.request(TOPICS["ctl"], "omnirotor_msgs/msg/FlightRequest", req,
                                "omnirotor_msgs/msg/FlightReply", 5.0)  # fmt: skip
    assert reply is not None and reply.accepted
    assert reply.message.startswith(f"mode disarmed; link up: plant session {PLANT:016x} (pinned), ")
    m = re.search(
        r", (\d+) frames followed, 0 bad, (\d+) of other plant sessions refused \(1 session\(s\)\)", reply.message
    )
    assert m and int(m[1]) >= 1 and int(m[2]) >= 5, reply.message
    assert reply.message.endswith("; controller session 1a2b3c4d5e6f7081")


def test_a_plant_pinned_to_another_node_is_said_with_both_ways_out():
    """A restarted node (a new random session) and a plant still pinned to the old one: the plant's status names
    the session it obeys, and the node says how to pair again, either way (issue 26 item 5: restarts)."""
    from omnirotor.rosmsg.convert import SIM_STATUS

    old = 0x0123456789ABCDEF
    said: list[str] = []
    options = NodeOptions(lockstep=True, status_hz=200.0, session_id=0x1A2B3C4D5E6F7081)
    with _scripted_plant("/restarted", _Controller(), _Director(), options, said.append) as p:
        status = p.plant.publisher("/omnirotor/sim_status", SIM_STATUS, block=True)
        _until_answered(p, 1, 0.001)
        seq, deadline = 2, time.monotonic() + 10
        while not any("the plant obeys" in line for line in said) and time.monotonic() < deadline:
            status.put(_sim_status(paired_session_id=old, lockstep=True))
            p.send(seq, 0.001 * seq)
            seq += 1
            time.sleep(0.005)
    assert [line for line in said if "the plant obeys" in line] == [
        f"the plant obeys controller session {old:016x}, not this node's 1a2b3c4d5e6f7081: its commands are refused "
        f"(pin the plant to this node: --pair-session 1a2b3c4d5e6f7081; if the node it obeys is gone, a restarted "
        f"one, start this node with --session-id {old:016x})"
    ]


def test_a_mission_names_its_plant_and_a_pinned_node_refuses_another_s(capsys):
    """``--mission-from-sim`` hears which plant session served the mission (said); pinned with ``--plant-session``
    to another (a second simulator answered first), the node stops at once: one line, exit 2 (issue 26 item 5)."""
    from omnirotor.cli import main
    from omnirotor.experiments.tasks.common import ExperimentOptions
    from omnirotor.fly.node import mission_from_sim
    from omnirotor.rosmsg import typestore
    from omnirotor.sitl.server import TOPICS, mission_json

    T = typestore().types
    port, ns = free_port(), "/mission_of"
    mission = mission_json("hover", ExperimentOptions(), False, PLANT)
    with (
        open_transport(listen=[f"tcp/127.0.0.1:{port}"], namespace=ns) as sim,
        open_transport(listen=[], connect=[f"tcp/127.0.0.1:{port}"], namespace=ns) as node,
    ):
        sim.serve(TOPICS["mission"], "std_msgs/msg/String", "std_msgs/msg/String",
                  lambda req: T["std_msgs/msg/String"](data=mission))  # fmt: skip
        task, _, lockstep, served_by = mission_from_sim(node, timeout_s=10.0)
        assert (task, lockstep, served_by) == ("hover", False, PLANT)
        argv = ["fly", "--mission-from-sim", "--plant-session", f"{FOREIGN:016x}", "--connect",
                f"tcp/127.0.0.1:{port}", "--listen", f"tcp/127.0.0.1:{free_port()}", "--namespace", ns]  # fmt: skip
        assert main(argv) == 2
    err = capsys.readouterr().err
    assert (
        f"omnirotor: error: the mission came from plant session {PLANT:016x}, not the --plant-session "
        f"{FOREIGN:016x} (another simulator answered first; stop it, or follow that one)\n"
    ) in err
    assert "Traceback" not in err
