"""The flight transport's figures: two real processes over Zenoh on loopback (issue 24, item 5).

``python benchmarks/bench_transport.py [--quick] [--json]`` (also ``python benchmarks/run.py --transport``):

* lockstep SITL (``omnirotor sim --serve --task hover --lockstep`` + ``omnirotor fly --mission-from-sim``): the
  frame-to-command round trip seen by the simulator (frame published -> the node's command received, the node's
  controller step and publishing included; p50, p99, max) and the real-time factor, with and without the ROS
  views (Imu, PoseStamped, RotorSpeeds published beside the frame every period);
* real-time SITL (the same hover on the wall clock): the node's periods late by more than 0.5 ms per 10^5, its
  frame-to-command latency inside the node, and its CPU time per frame (the process's, Zenoh's threads included,
  and its loop thread's alone); quiet, and with a CPU hog (a busy Python process) pinned on the other core;
* real-time SITL under a flood (issue 26 item 5): a third process, connected to both, publishes at ten times the
  loop's rate (10 kHz on each key) well-formed rotor commands of a foreign session with full speeds on the command
  key, and bogus frames (random bytes, truncated frames, well-formed frames of a foreign plant session with forged
  numbers) on the frame key; the node's periods late beside the quiet figure, and what each side counted and
  dropped. Two modes: *after* pairing (both sides first come, the flood from when the simulator has paired with the
  node to the end) and *before* the node (the flood from before the node starts, both sides pinned: the simulator
  to the node's session with ``--pair-session``, the node to the simulator's with ``--plant-session``; first come,
  the flood would take either pairing: docs/transport.md).

* real-time SITL under a ``ctl`` flood (issue 26's "any process may send ctl requests"): a third process connected to
  the node sends ``FlightRequest`` queries as fast as the node answers them (:data:`CTL_OUTSTANDING` in flight),
  well-formed ``status`` requests (``ctl-status``) or malformed ones (``ctl-malformed``: random bytes, a truncated
  request, an unknown kind, a 5000-character name), from when the node flies to the run's end: the node's periods
  late, its frame-to-command p99, the hover's verdict, and the requests answered, refused and answered busy (the
  node's bound, ``omnirotor fly --ctl-rate``) on both sides;
* the tracking against the in-process run: the same seeded hover flown by ``omnirotor run hover`` in one process,
  and each real-time run's RMS error per axis (the true pose's, the run JSON's ``ee_rms_error_true``) beside it,
  with the share of the plant's periods held (no fresh command: ``commands_held``) and of the node's periods late,
  and the gap's least-squares slope against the held share (``--repeats N`` quiet runs; the hog and flood runs
  are rows too). It was a test's assertion until session 14 (within 0.5 cm of the in-process run); the periods
  held decide it, a speed of the machine.

``--flood-only``: the flood cases alone (after a warm-up); ``--flood-mode MODE``: one of them.

``--transport-priority P``: both processes' ``--transport-priority P`` in every real-time run (their loops at
``--fifo-priority`` :data:`LOOP_PRIORITY`). ``--compare-transport-priority P [--rounds N] [--seconds S]``: the
quiet real-time hover and the CPU-hog case without and with it, interleaved (each round: quiet, hog, each without
and with, the order alternating by round), N rounds of S s each: per run the node's late periods per 10^5, its
frame-to-command p99, the plant's share of periods held (no fresh command), link losses; then the medians.

The machine's CPU count and load average before and after are part of the result: figures on a loaded machine
are not the issue's quiet-machine figures.

Goals of the issue (quiet machine): round trip p99 <= 250 µs; <= 0.1 % of periods late (100 per 10^5);
lockstep >= 5x real time. Never part of the test suite.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import socket
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
CLI = "import sys; from omnirotor.cli import main; sys.argv[0] = 'omnirotor'; main()"
GOALS = {"round_trip_p99_us": 250.0, "late_per_1e5": 100.0, "lockstep_rtf": 5.0}


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO / "src")] + ([env["PYTHONPATH"]] if "PYTHONPATH" in env else []))
    return env


FLOOD_HZ = 10_000
"""The flood's rate on each key [messages/s]: ten times the loop's."""

TRACKING_AXES = ("x_cm", "y_cm", "z_cm", "roll_deg", "pitch_deg", "yaw_deg")
"""The run JSON's RMS errors compared with the in-process run (``ee_rms_error_true``: the true pose's)."""


SIM_AFTER_NODE_S = 60.0
"""How long the simulator may run on after the node exited, beyond the run's duration, before the pair is failed."""

FLOOD_MODES = ("after", "before")
"""When the flood starts (module docstring): after the simulator paired with the node, or before the node."""
CTL_MODES = ("ctl-status", "ctl-malformed")
"""The ``ctl`` floods at the node (module docstring): well-formed ``status`` requests, or malformed ones."""
BENCH_SESSION = "be4c4000000000a1"
"""The node's session id in the flood's *before* mode (``fly --session-id``, ``sim --pair-session``)."""
BENCH_PLANT = "be4c4000000000b3"
"""The simulator's session id in the flood's *before* mode (``sim --session-id``, ``fly --plant-session``)."""
FORGED_PLANT = 0xF0E1F0E1F0E1F0E1
"""The plant session of the flood's well-formed frames (a second plant's, or a forger's)."""


def flood(endpoints: list[str], namespace: str, duration_s: float, mode: str = "after",
          rate_hz: float = FLOOD_HZ) -> dict:  # fmt: skip
    """Publish foreign commands and bogus frames at ``rate_hz`` each for ``duration_s`` (module docstring).

    ``mode`` "after": from when the simulator has paired; "before": at once (a line ``flooding`` on stdout when the
    first burst is out, for the caller to start the node then).
    """
    import time

    import numpy as np

    from omnirotor.messages import new_frame
    from omnirotor.rosmsg.convert import COMMAND, FRAME, WireMessages
    from omnirotor.sitl.server import TOPICS
    from omnirotor.transport import open_transport

    rng = np.random.default_rng(11)
    with open_transport(namespace=namespace, listen=[], connect=endpoints) as t:
        cmd, frame = t.publisher(TOPICS["rotor_cmd"], COMMAND), t.publisher(TOPICS["frame"], FRAME)
        w = WireMessages(8)
        w.command.session_id, w.command.hz[:], w.command.state = 0x5EED, 400.0, 1
        w.frame.session_id = FORGED_PLANT
        valid = bytes(frame.serialize(w.fill_frame(new_frame(8), 1)))
        bogus = [rng.bytes(int(n)) for n in rng.integers(1, 600, 8)] + [valid[: len(valid) // 2], valid[:40]]
        forged = []
        for seq in (10**9, 2**62, 5):
            forged.append(bytes(frame.serialize(w.fill_frame(new_frame(8), seq))))
        frames = bogus + forged
        # "after": from when the simulator has paired with the node (a flood before the node's first command pairs a
        # first-come simulator with the flood's session; docs/transport.md); "before": at once (a pinned simulator)
        status = t.subscriber(TOPICS["sim_status"], "omnirotor_msgs/msg/SimStatus", depth=4)
        paired_by = time.monotonic() + 600.0
        m = None
        while mode == "after" and (m is None or m.paired_session_id == 0):
            if time.monotonic() > paired_by:
                raise RuntimeError("the simulator did not pair with the node within 600 s")
            m = status.take_latest(0.1)
        burst = max(1, int(round(rate_hz / 1000)))
        sent = 0
        t0 = time.monotonic()
        end = t0 + duration_s
        k = 0
        while time.monotonic() < end:
            for _ in range(burst):
                w.command.seq = sent + 1
                cmd.put(w.command)
                frame.put_raw(frames[sent % len(frames)])
                sent += 1
            if k == 0 and mode == "before":
                print("flooding", flush=True)
            k += 1
            left = t0 + k * 0.001 - time.monotonic()
            if left > 0:
                time.sleep(left)
        return {"sent_per_key": sent, "rate_hz": sent / max(time.monotonic() - t0, 1e-9)}


CTL_KINDS = ("status", "malformed")
"""What a ``ctl`` flood sends: well-formed ``status`` requests, or malformed ones (module docstring)."""
CTL_OUTSTANDING = 32
"""Requests the ``ctl`` flood keeps in flight at once (it sends the next as soon as one is answered or timed out)."""


def ctl_payloads(kind: str) -> list[bytes]:
    """The ``ctl`` flood's request payloads: a well-formed ``status``, or malformed ones (module docstring)."""
    import numpy as np

    from omnirotor.fly.requests import FlightRequest
    from omnirotor.rosmsg import msg_type, typestore

    store, name = typestore(), "omnirotor_msgs/msg/FlightRequest"
    good = FlightRequest("status").to_msg()
    if kind == "status":
        return [bytes(store.serialize_cdr(good, name))]
    rng = np.random.default_rng(12)
    fields = {f: getattr(good, f) for f in ("height_m", "setpoint", "depth_m", "force")}
    bad_kind = msg_type(name)(kind=200, name="", **fields)  # decodes, an unknown kind
    long_name = msg_type(name)(kind=6, name="x" * 5000, **fields)  # a preset name of 5000 characters
    valid = bytes(store.serialize_cdr(good, name))
    decoding = [bytes(store.serialize_cdr(m, name)) for m in (bad_kind, long_name)]
    return [rng.bytes(int(n)) for n in rng.integers(1, 300, 4)] + [valid[: len(valid) // 2], *decoding]


def ctl_flood(endpoint: str, namespace: str, duration_s: float, kind: str) -> dict:
    """Send ``ctl`` requests at the node as fast as it takes them for ``duration_s``, from when it flies.

    :data:`CTL_OUTSTANDING` requests in flight at once (Zenoh queries, each with a 2 s time-out, as ``ctl``'s);
    the replies are counted: accepted, refused, refused as busy (the node's bound), and requests never answered.
    """
    import threading
    import time

    import zenoh

    from omnirotor.fly.requests import CTL_TOPIC, FlightReply
    from omnirotor.rosmsg import typestore
    from omnirotor.rosmsg.convert import LOOP_STATUS
    from omnirotor.transport import open_transport
    from omnirotor.transport.base import ros_topic
    from omnirotor.transport.zenoh_transport import key_expression

    with open_transport(namespace=namespace, listen=[], connect=[endpoint]) as t:  # from when the node flies
        loop = t.subscriber("/omnirotor/loop_status", LOOP_STATUS, depth=4)
        by = time.monotonic() + 900.0
        while (m := loop.take_latest(0.1)) is None or m.frames < 100:
            if time.monotonic() > by:
                raise RuntimeError("the node did not fly within 900 s")
    payloads = ctl_payloads(kind)
    key = key_expression(0, ros_topic(namespace, CTL_TOPIC), "omnirotor_msgs/msg/FlightRequest")
    store = typestore()
    counts = {"sent": 0, "accepted": 0, "refused": 0, "busy": 0, "replies": 0, "unanswered": 0}
    lock = threading.Lock()
    slots = threading.Semaphore(CTL_OUTSTANDING)
    conf = zenoh.Config()
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("listen/endpoints", "[]")
    conf.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(conf)  # not closed: the peer's process ends at once after its report (main)

    def on_reply(reply) -> None:
        with lock:
            counts["replies"] += 1
            if reply.ok is None:
                return
            try:
                r = FlightReply.from_msg(store.deserialize_cdr(reply.ok.payload.to_bytes(),
                                                               "omnirotor_msgs/msg/FlightReply"))  # fmt: skip
            except Exception:  # noqa: BLE001  (an answer that is not a reply: counted as a reply only)
                return
            counts["accepted" if r.accepted else "busy" if r.message.startswith("busy") else "refused"] += 1

    t0 = time.monotonic()
    end = t0 + duration_s
    while time.monotonic() < end:
        if not slots.acquire(timeout=0.1):
            continue
        counts["sent"] += 1
        session.get(key, payload=payloads[counts["sent"] % len(payloads)], timeout=2.0,
                    handler=zenoh.handlers.Callback(on_reply, slots.release))  # fmt: skip
    elapsed = time.monotonic() - t0
    drained = time.monotonic() + 3.0  # the last ones answered or timed out (2 s), within one bound
    for _ in range(CTL_OUTSTANDING):
        slots.acquire(timeout=max(drained - time.monotonic(), 0.0))
    answered = counts["accepted"] + counts["refused"] + counts["busy"]
    counts["unanswered"] = counts["sent"] - answered
    cpu = time.process_time()  # the flooder's own CPU (its Python and Zenoh's threads): taken from the pair's cores
    return {**counts, "rate_hz": counts["sent"] / max(elapsed, 1e-9), "kind": kind, "cpu_s": cpu, "s": elapsed}


LOOP_PRIORITY = 20
"""Both loops' ``--fifo-priority`` in the real-time runs."""


def run_pair(duration_s: float, lockstep: bool, ros_views: bool, fifo: bool, flood_mode: str | None = None,
             ctl_rate: float | None = None, transport_priority: int = 0) -> dict:  # fmt: skip
    """One SITL hover: the simulator's run JSON, its ``sitl`` report and the node's summary, under a flood in
    ``flood_mode`` (``ctl_rate``: the node's ``--ctl-rate``, None its default; ``transport_priority``: both
    processes' ``--transport-priority`` when ``fifo``, 0 not asked)."""
    port, node_port = _port(), _port()
    ns = f"/bench{port}"
    sim_cmd = [sys.executable, "-c", CLI, "sim", "--serve", "--task", "hover", "--duration", str(duration_s),
               "--listen", f"tcp/127.0.0.1:{port}", "--namespace", ns, "--json", "--wait", "900"]  # fmt: skip
    loop = str(LOOP_PRIORITY) if fifo and not lockstep else "0"
    sim_cmd += ["--lockstep"] if lockstep else ["--fifo-priority", loop]
    sim_cmd += [] if ros_views else ["--no-ros-views"]
    node_cmd = [sys.executable, "-c", CLI, "fly", "--mission-from-sim", "--connect", f"tcp/127.0.0.1:{port}",
                "--listen", f"tcp/127.0.0.1:{node_port}", "--namespace", ns, "--json",
                "--fifo-priority", loop]  # fmt: skip
    if transport_priority and loop != "0":
        sim_cmd += ["--transport-priority", str(transport_priority)]
        node_cmd += ["--transport-priority", str(transport_priority)]
    node_cmd += [] if ctl_rate is None else ["--ctl-rate", f"{ctl_rate:g}"]
    if flood_mode == "before":  # pinned pairing both ways: the flood that comes first must take neither
        sim_cmd += ["--pair-session", BENCH_SESSION, "--session-id", BENCH_PLANT]
        node_cmd += ["--session-id", BENCH_SESSION, "--plant-session", BENCH_PLANT]
    pipe = subprocess.PIPE
    # the pair's output to files, not pipes: neither blocks on a full pipe while the other is waited for
    outs = [tempfile.TemporaryFile("w+") for _ in range(5)]
    sim = subprocess.Popen(sim_cmd, stdout=outs[0], stderr=outs[1], env=_env(), text=True)
    node = flooder = None
    try:
        if flood_mode in FLOOD_MODES:  # the flooder's own wait ("after"), or the node started once it floods ("before")
            flood_cmd = [sys.executable, __file__, "--flood-peer", f"tcp/127.0.0.1:{port},tcp/127.0.0.1:{node_port}",
                         ns, str(duration_s + 600), flood_mode]  # fmt: skip
            flooder = subprocess.Popen(flood_cmd, stdout=pipe, stderr=subprocess.DEVNULL, env=_env(), text=True)
        elif flood_mode is not None:  # ctl-<kind>: requests at the node's ctl endpoint, from when it flies
            flood_cmd = [sys.executable, __file__, "--ctl-peer", f"tcp/127.0.0.1:{node_port}", ns,
                         str(max(duration_s - 1.0, 1.0)),
                         flood_mode.removeprefix("ctl-")]  # fmt: skip
            flooder = subprocess.Popen(flood_cmd, stdout=pipe, stderr=outs[4], env=_env(), text=True)
            if flood_mode == "before" and flooder.stdout.readline().strip() != "flooding":
                raise RuntimeError("the flood did not start")
        node = subprocess.Popen(node_cmd, stdout=outs[2], stderr=outs[3], env=_env(), text=True)
        node.wait(timeout=1800)
        try:  # the simulator ends its run soon after the node (its failsafe, at worst): a bounded wait
            sim.wait(timeout=SIM_AFTER_NODE_S + duration_s)
        except subprocess.TimeoutExpired:
            sim.kill()
            sim.wait()
            outs[1].write(f"\n(bench: killed, still running {SIM_AFTER_NODE_S + duration_s:.0f} s after the node "
                          "exited)")  # fmt: skip
        ctl = None
        if flooder is not None and flood_mode not in FLOOD_MODES:  # its own end: the run's duration, then replies
            try:
                ctl = json.loads(flooder.communicate(timeout=60)[0].strip().splitlines()[-1])
            except (subprocess.TimeoutExpired, ValueError, IndexError):
                ctl = None
    finally:  # the flooder (its end is ours), and the pair when it did not finish
        for p in (sim, node, flooder):
            if p is not None and p.poll() is None:
                p.kill()
                p.wait()
    sim_out, sim_err, node_out, node_err, ctl_err = (_read(f) for f in outs)
    if flood_mode is not None and flood_mode not in FLOOD_MODES and ctl is None:
        raise RuntimeError(f"the ctl flood did not report: {ctl_err[-800:]!r}")
    try:
        run = json.loads(sim_out)
        out = {"sim": run["sitl"], "node": json.loads(node_out.strip().splitlines()[-1]), "run": run}
    except (ValueError, KeyError, IndexError):
        raise RuntimeError(f"the pair did not finish: simulator said {sim_err[-800:]!r}; node said "
                           f"{node_err[-800:]!r}") from None  # fmt: skip
    if ctl is not None:
        out["ctl"] = ctl
    return out


def _read(f) -> str:
    """All a temporary output file holds (and closes it)."""
    with f:
        f.flush()
        f.seek(0)
        return f.read()


@contextlib.contextmanager
def cpu_hog(cpu: int):
    """A busy process pinned on ``cpu`` while the block runs."""
    hog = subprocess.Popen([sys.executable, "-c", f"import os; os.sched_setaffinity(0, {{{cpu}}})\nwhile True: pass"])
    try:
        yield
    finally:
        hog.kill()
        hog.wait()


def real_time_figures(r: dict) -> dict:
    """A real-time run's figures (:func:`run_pair`'s result): the node's deadlines and CPU, what the sides dropped."""
    node, sim = r["node"], r["sim"]
    return {
        "periods": node["periods"],
        "late": node["periods_late"],
        "late_per_1e5": node["late_per_1e5"],
        "missed": node["missed"],
        "worst_late_ms": node["worst_late_ms"],
        "frame_to_command_us": node["frame_to_command_us"],
        "node_cpu_per_frame_us": node["cpu_per_frame_us"],
        "node_loop_cpu_per_frame_us": node.get("loop_cpu_per_frame_us"),
        "node_frames_bad": node["frames_bad"],
        "node_frames_foreign": node.get("frames_foreign", 0),
        "sim_late_steps": sim["late_steps"],
        "sim_commands_obeyed": sim["commands_obeyed"],
        "sim_commands_held": sim["commands_held"],
        "sim_commands_refused": sim["commands_refused"],
        "sim_foreign_sessions": sim["foreign_sessions"],
        "sim_failsafe": sim["failsafe"],
    }


def in_process_hover(duration_s: float) -> dict:
    """The same seeded hover flown in process (``omnirotor run hover --duration``): its run JSON."""
    cmd = [sys.executable, "-c", CLI, "run", "hover", "--duration", str(duration_s), "--json"]
    done = subprocess.run(cmd, capture_output=True, text=True, env=_env(), timeout=1800, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"the in-process hover failed: {done.stderr[-800:]!r}")
    return json.loads(done.stdout)


def tracking_row(case: str, r: dict, ref: dict) -> dict:
    """One real-time run's tracking against the in-process run ``ref``: RMS per axis, its gap, the periods held.

    A run the plant's failsafe cut has no metrics (docs/transport.md): its row says so, with empty RMS and gap.
    """
    rms, sim, node = r["run"].get("ee_rms_error_true") or {}, r["sim"], r["node"]
    axes = [a for a in TRACKING_AXES if a in rms and a in ref["ee_rms_error_true"]]
    return {
        "case": case,
        "failsafe": bool(sim["failsafe"]),
        "rms": {a: rms[a] for a in axes},
        "gap": {a: rms[a] - ref["ee_rms_error_true"][a] for a in axes},
        "held_share": sim["commands_held"] / max(sim["steps"], 1),
        "late_share": node["periods_late"] / max(node["periods"], 1),
        "success": r["run"].get("success"),
    }


def gap_growth(rows: list[dict]) -> dict:
    """The RMS gap's least-squares slope against the share of periods held, per axis [unit per 10 % held].

    None where the runs do not establish it: fewer than three, or their held shares within 1 % of each other.
    """
    import numpy as np

    rows = [row for row in rows if row["rms"]]  # runs with metrics
    held = np.array([row["held_share"] for row in rows])
    out: dict = {"runs": len(rows), "held_share_range": [float(held.min()), float(held.max())] if rows else None}
    ok = len(rows) >= 3 and float(np.ptp(held)) >= 0.01
    for a in TRACKING_AXES:
        gaps = [row["gap"].get(a) for row in rows]
        if not ok or any(g is None for g in gaps):
            out[a] = None
            continue
        slope, intercept = np.polyfit(held, np.array(gaps), 1)
        out[a] = {"per_10pct_held": 0.1 * float(slope), "at_0_held": float(intercept)}
    return out


def collect(quick: bool, flood_only: bool = False, note=lambda msg: print(msg, file=sys.stderr),
            flood_modes: tuple[str, ...] = FLOOD_MODES + CTL_MODES, repeats: int | None = None,
            ctl_rate: float | None = None, transport_priority: int = 0) -> dict:  # fmt: skip
    """Every figure of the module docstring (``flood_only``: the flood cases alone, in ``flood_modes``).

    ``repeats``: quiet real-time runs (default 1 quick, 3 full), each a row of the tracking table; ``ctl_rate``: the
    node's ``--ctl-rate`` in every run (None: its default); ``transport_priority``: both processes'
    ``--transport-priority`` in every real-time run (0: not asked).
    """
    lock_s, rt_s = (2.0, 10.0) if quick else (10.0, 100.0)
    repeats = (1 if quick else 3) if repeats is None else repeats
    out: dict = {"quick": quick, "lockstep_s": lock_s, "real_time_s": rt_s, "goals": GOALS,
                 "load_before": os.getloadavg(), "cpus": os.cpu_count(), "node_ctl_rate": ctl_rate,
                 "transport_priority": transport_priority}  # fmt: skip
    note("warm-up (numba cache)")
    run_pair(0.2, lockstep=True, ros_views=False, fifo=False)
    for views in () if flood_only else (False, True):
        note(f"lockstep hover {lock_s:g} s, ROS views {'on' if views else 'off'}")
        r = run_pair(lock_s, lockstep=True, ros_views=views, fifo=False)
        out[f"lockstep_views_{'on' if views else 'off'}"] = {
            "round_trip_us": r["sim"]["round_trip_us"],
            "rtf": r["sim"]["real_time_factor"],
            "node_cpu_per_frame_us": r["node"]["cpu_per_frame_us"],
            "node_loop_cpu_per_frame_us": r["node"].get("loop_cpu_per_frame_us"),
            "node_work_us": r["node"]["work_us"],
        }
    note(f"the same hover {rt_s:g} s in process (omnirotor run hover): the tracking's reference")
    ref = in_process_hover(rt_s)
    rows: list[dict] = []
    n_cpus = os.cpu_count() or 1
    cases = [] if flood_only else [("real_time", False)] + [(f"real_time_{k + 2}", False) for k in range(repeats - 1)]
    for case, hog in cases + ([] if flood_only else [("real_time_hog", True)]):
        note(f"real-time hover {rt_s:g} s{' with a CPU hog on CPU 0' if hog else ''} ({case})")
        with cpu_hog(0) if hog and n_cpus > 1 else contextlib.nullcontext():
            r = run_pair(rt_s, lockstep=False, ros_views=True, fifo=True, ctl_rate=ctl_rate,
                         transport_priority=transport_priority)  # fmt: skip
        out[case] = real_time_figures(r)
        rows.append(tracking_row(case, r, ref))
    for mode in flood_modes:
        if mode in CTL_MODES:
            what = f"{mode.removeprefix('ctl-')} ctl requests from a third process, as fast as the node takes them"
        else:
            what = f"a flood ({FLOOD_HZ} foreign commands and bogus frames per second) " + (
                "from the pairing on" if mode == "after" else "from before the node, both sides pinned"
            )
        note(f"real-time hover {rt_s:g} s under {what}")
        r = run_pair(rt_s, lockstep=False, ros_views=True, fifo=True, flood_mode=mode, ctl_rate=ctl_rate,
                     transport_priority=transport_priority)  # fmt: skip
        case = f"real_time_flood_{mode.replace('-', '_')}"
        out[case] = real_time_figures(r)
        out[case]["hover_success"] = r["run"].get("success")
        if "ctl" in r:
            out[case]["ctl"] = r["ctl"]
            out[case]["node_requests"] = r["node"].get("requests")
        rows.append(tracking_row(case, r, ref))
    out["tracking"] = {"in_process_rms": {a: ref["ee_rms_error_true"][a] for a in TRACKING_AXES
                                          if a in ref["ee_rms_error_true"]},
                       "in_process_success": ref.get("success"), "rows": rows, "growth": gap_growth(rows)}  # fmt: skip
    out["load_after"] = os.getloadavg()
    return out


def compare_transport_priority(priority: int, rounds: int, seconds: float,
                               note=lambda msg: print(msg, file=sys.stderr)) -> dict:  # fmt: skip
    """The quiet and CPU-hog real-time hovers without and with ``--transport-priority priority``, interleaved.

    Each round flies four runs: quiet and hog, each without and with, "without" first in even rounds and "with"
    first in odd ones. A pair that did not finish is a run that says so (its error), not an end of the benchmark.
    """
    out: dict = {"transport_priority": priority, "loop_priority": LOOP_PRIORITY, "rounds": rounds,
                 "seconds": seconds, "load_before": os.getloadavg(), "cpus": os.cpu_count(), "runs": []}  # fmt: skip
    note("warm-up (numba cache)")
    run_pair(0.2, lockstep=True, ros_views=False, fifo=False)
    hog_cpu = 0 if (os.cpu_count() or 1) > 1 else None
    for k in range(rounds):
        for hog in (False, True):
            for prio in (0, priority) if k % 2 == 0 else (priority, 0):
                note(f"round {k + 1}/{rounds}: real-time hover {seconds:g} s, {'CPU hog on CPU 0' if hog else 'quiet'}"
                     f", transport priority {prio or 'not asked'}")  # fmt: skip
                row: dict = {"round": k + 1, "hog": hog, "transport_priority": prio}
                try:
                    with cpu_hog(hog_cpu) if hog and hog_cpu is not None else contextlib.nullcontext():
                        r = run_pair(seconds, lockstep=False, ros_views=True, fifo=True, transport_priority=prio)
                except RuntimeError as exc:
                    row["error"] = str(exc)[-300:]
                else:
                    sim, node = r["sim"], r["node"]
                    row.update(late_per_1e5=node["late_per_1e5"], p99_us=node["frame_to_command_us"].get("p99"),
                               held_share=sim["commands_held"] / max(sim["steps"], 1),
                               link_lost=bool(node.get("link_lost")), failsafe=bool(sim["failsafe"]),
                               worst_late_ms=node["worst_late_ms"])  # fmt: skip
                note(f"  {row}")
                out["runs"].append(row)
    out["load_after"] = os.getloadavg()
    return out


def render_comparison(c: dict) -> str:
    """:func:`compare_transport_priority`'s runs and medians as Markdown."""
    import statistics

    load = f"{c['cpus']} CPUs, load average {c['load_before'][0]:.1f} before, {c['load_after'][0]:.1f} after"
    lines = [f"Transport priority: loops at SCHED_FIFO {c['loop_priority']}, the transport's threads at "
             f"{c['transport_priority']} or not asked; {c['rounds']} interleaved rounds of {c['seconds']:g} s "
             f"real-time hovers ({load}):", "",
             "| case | transport priority | runs | late per 1e5 (each) | median | p99 frame to command [µs] (median) | "
             "plant periods held (each) | median | link lost / failsafe |",
             "|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for hog in (False, True):
        for prio in (0, c["transport_priority"]):
            rs = [r for r in c["runs"] if r["hog"] == hog and r["transport_priority"] == prio]
            ok = [r for r in rs if "error" not in r]
            if not ok:
                continue
            late = [r["late_per_1e5"] for r in ok]
            held = [100 * r["held_share"] for r in ok]
            p99 = statistics.median(r["p99_us"] for r in ok)
            lost = sum(r["link_lost"] or r["failsafe"] for r in ok) + len(rs) - len(ok)
            lines.append(f"| {'CPU hog on CPU 0' if hog else 'quiet'} | {prio or 'not asked'} | {len(rs)} | "
                         f"{', '.join(f'{v:.0f}' for v in late)} | {statistics.median(late):.0f} | {p99:.0f} | "
                         f"{', '.join(f'{v:.2f} %' for v in held)} | {statistics.median(held):.2f} % | "
                         f"{lost} of {len(rs)} |")  # fmt: skip
    return "\n".join(lines)


def render(r: dict) -> str:
    """The figures as Markdown lines."""
    load = r.get("load_before"), r.get("load_after")
    where = f"{r.get('cpus')} CPUs, load average {load[0][0]:.1f} before, {load[1][0]:.1f} after" if all(load) else ""
    lines = [f"Transport (two processes over Zenoh on loopback; {'quick' if r['quick'] else 'full'} sizes; {where}):",
             ""]  # fmt: skip
    lines += ["| measurement | p50 | p99 | max | other |", "|---|---|---|---|---|"]
    for key, label in (("lockstep_views_off", "lockstep round trip, frame only"),
                       ("lockstep_views_on", "lockstep round trip, frame + ROS views")):  # fmt: skip
        if key not in r:  # --flood-only
            continue
        d = r[key]
        rt = d["round_trip_us"]
        lines.append(
            f"| {label} [µs] | {rt['p50']:.0f} | {rt['p99']:.0f} | {rt['max']:.0f} | {d['rtf']:.2f}x real time; "
            f"node CPU {d['node_cpu_per_frame_us']:.0f} µs/frame ({_loop(d)} in its loop) |"
        )
    flood_label = f"real time, flood ({FLOOD_HZ // 1000} kHz foreign commands + bogus frames)"
    repeats = [(k, f"real time, quiet (repeat {k.rsplit('_', 1)[1]})") for k in r if k[len("real_time_") :].isdigit()]
    for key, label in (("real_time", "real time, quiet"), *repeats, ("real_time_hog", "real time, CPU hog on CPU 0"),
                       ("real_time_flood_after", f"{flood_label} after the pairing"),
                       ("real_time_flood_before", f"{flood_label} before the node, both pinned"),
                       ("real_time_flood_ctl_status", "real time, ctl flood: status requests"),
                       ("real_time_flood_ctl_malformed", "real time, ctl flood: malformed requests")):  # fmt: skip
        if key not in r:
            continue
        d = r[key]
        f = d["frame_to_command_us"]
        lines.append(
            f"| {label}: node frame to command [µs] | {f['p50']:.0f} | {f['p99']:.0f} | {f['max']:.0f} | "
            f"late > 0.5 ms: {d['late']} of {d['periods']} ({d['late_per_1e5']:.0f} per 1e5), worst "
            f"{d['worst_late_ms']:.1f} ms; node CPU {d['node_cpu_per_frame_us']:.0f} µs/frame ({_loop(d)} in its "
            "loop)"
            + (
                f"; dropped: {d['node_frames_bad']} bogus and {d.get('node_frames_foreign', 0)} foreign frames "
                f"(node), {d['sim_commands_refused']} foreign commands (sim), {d['sim_commands_obeyed']} of the "
                "node's obeyed"
                if key in ("real_time_flood_after", "real_time_flood_before")
                else ""
            )
            + (_ctl(d) if "ctl" in d else "")
            + " |"
        )
    if "tracking" in r:
        lines += ["", *_tracking(r["tracking"])]
    return "\n".join(lines)


def _ctl(d: dict) -> str:
    """A ctl flood's counts, the client's and the node's, and the hover's verdict."""
    c, n = d["ctl"], d.get("node_requests") or {}
    return (
        f"; {c['sent']} requests sent ({c['rate_hz']:.0f}/s): {c['accepted']} accepted, {c['refused']} refused, "
        f"{c['busy']} busy, {c['unanswered']} unanswered; the node: {n.get('served', '?')} served, "
        f"{n.get('busy', '?')} busy, {n.get('bad', '?')} malformed (at most {n.get('rate_hz', '?')}/s); hover "
        + ("held" if d.get("hover_success") else "FAILED")
    )


def _tracking(tr: dict) -> list[str]:
    """The tracking table: each real-time run's RMS against the in-process run's, by the share of periods held."""
    ref = tr["in_process_rms"]
    axes = [a for a in TRACKING_AXES if a in ref]
    unit = {a: a.rsplit("_", 1)[1] for a in axes}
    head = " | ".join(f"{a.split('_')[0]} [{unit[a]}]" for a in axes)
    lines = [
        "Tracking against the same seeded hover flown in process (true pose's RMS error; gap = transport - in "
        "process; held: the plant's periods without a fresh command, late: the node's periods late or missed):",
        "",
        f"| run | held | late | {head} | verdict |",
        "|---|---|---|" + "---|" * len(axes) + "---|",
        "| in process | - | - | " + " | ".join(f"{ref[a]:.2f}" for a in axes) + " | "
        + ("held" if tr.get("in_process_success") else "FAILED") + " |",
    ]  # fmt: skip
    for row in sorted(tr["rows"], key=lambda x: x["held_share"]):
        cells = " | ".join(f"{row['rms'][a]:.2f} ({row['gap'][a]:+.2f})" if a in row["rms"] else "-" for a in axes)
        verdict = "cut by the failsafe (no metrics)" if row["failsafe"] else "held" if row["success"] else "FAILED"
        lines.append(f"| {row['case']} | {100 * row['held_share']:.1f} % | {100 * row['late_share']:.1f} % | "
                     f"{cells} | {verdict} |")  # fmt: skip
    g = tr["growth"]
    if all(g.get(a) is None for a in axes):
        runs = f"{g['runs']} run" + ("" if g["runs"] == 1 else "s")
        lines += ["", f"Gap against the held share: not established ({runs}; it takes three at different shares)."]
    else:
        lo, hi = g["held_share_range"]
        fits = ", ".join(f"{a.split('_')[0]} {g[a]['per_10pct_held']:+.2f} {unit[a]}" for a in axes if g.get(a))
        lines += ["", f"Gap against the held share (least squares over {g['runs']} runs, held {100 * lo:.0f}-"
                      f"{100 * hi:.0f} %), per 10 % of periods held: {fits}."]  # fmt: skip
    return lines


def plot_tracking(tr: dict, path: str) -> None:
    """The tracking table as a figure: each run's RMS gap to the in-process run against the share of periods held."""
    import matplotlib.pyplot as plt

    from omnirotor.experiments.figures import save_figure

    rows = [row for row in tr["rows"] if row["rms"]]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), layout="constrained")
    for ax, group, unit in ((axes[0], ("x_cm", "y_cm", "z_cm"), "cm"), (axes[1], ("roll_deg", "pitch_deg", "yaw_deg"),
                                                                         "deg")):  # fmt: skip
        for a, marker in zip(group, "o^s", strict=True):
            pts = [(100 * row["held_share"], row["gap"][a]) for row in rows if a in row["gap"]]
            if pts:
                ax.scatter(*zip(*pts, strict=True), marker=marker, label=a.split("_")[0])
        ax.axhline(0.0, color="0.5", lw=0.8)
        ax.set_xlabel("plant periods held (no fresh command) [%]")
        ax.set_ylabel(f"RMS error, transport - in process [{unit}]")
        ax.legend()
    cut = len(tr["rows"]) - len(rows)
    fig.suptitle(f"Real-time hover over the transport against the same hover in process ({len(rows)} run"
                 + ("" if len(rows) == 1 else "s")
                 + (f"; {cut} cut by the plant's failsafe, not shown" if cut else "") + ")")  # fmt: skip
    save_figure(fig, path)


def _loop(d: dict) -> str:
    v = d.get("node_loop_cpu_per_frame_us")
    return "?" if v is None else f"{v:.0f}"


def main(argv: list[str] | None = None) -> int:
    """Command line (module docstring)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="shorter runs (2 s lockstep, 10 s real time)")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--flood-only", action="store_true", help="the flood cases alone (every mode)")
    ap.add_argument("--flood-mode", choices=FLOOD_MODES + CTL_MODES, help="only this flood mode (default: every one)")
    ap.add_argument("--repeats", type=int, help="quiet real-time runs (default: 1 quick, 3 full)")
    ap.add_argument("--plot", metavar="PNG", help="also draw the tracking table into this PNG file")
    ap.add_argument("--node-ctl-rate", type=float, help="the node's --ctl-rate (default: its own; 1000: one a period)")
    ap.add_argument(
        "--transport-priority",
        type=int,
        default=0,
        help=f"both processes' --transport-priority in the real-time runs (below {LOOP_PRIORITY})",
    )
    ap.add_argument(
        "--compare-transport-priority",
        type=int,
        metavar="P",
        help="only the quiet and hog hovers without and with --transport-priority P, interleaved",
    )
    ap.add_argument("--rounds", type=int, default=3, help="rounds of --compare-transport-priority (default 3)")
    ap.add_argument("--seconds", type=float, default=30.0, help="each run of --compare-transport-priority [s]")
    ap.add_argument("--flood-peer", nargs=4, metavar=("ENDPOINTS", "NAMESPACE", "SECONDS", "MODE"),
                    help=argparse.SUPPRESS)  # fmt: skip
    ap.add_argument("--ctl-peer", nargs=4, metavar=("ENDPOINT", "NAMESPACE", "SECONDS", "KIND"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.flood_peer:
        endpoints, ns, seconds, mode = args.flood_peer
        print(json.dumps(flood(endpoints.split(","), ns, float(seconds), mode)))
        return 0
    if args.ctl_peer:
        endpoint, ns, seconds, kind = args.ctl_peer
        print(json.dumps(ctl_flood(endpoint, ns, float(seconds), kind)), flush=True)
        os._exit(0)  # Zenoh's threads may hold the interpreter's exit
    if args.repeats is not None and not 1 <= args.repeats <= 20:
        ap.error(f"--repeats must be 1 to 20, got {args.repeats}")
    for prio in (args.transport_priority, args.compare_transport_priority):
        if prio is not None and not 0 <= prio < LOOP_PRIORITY:
            ap.error(f"a transport priority must be in 0..{LOOP_PRIORITY - 1} (below the loops'), got {prio}")
    if args.compare_transport_priority is not None:
        if not (args.compare_transport_priority > 0 and 1 <= args.rounds <= 20 and args.seconds > 0):
            ap.error("--compare-transport-priority needs P >= 1, --rounds 1 to 20 and --seconds > 0")
        c = compare_transport_priority(args.compare_transport_priority, args.rounds, args.seconds)
        print(json.dumps(c, indent=1) if args.json else render_comparison(c))
        return 0
    modes = (args.flood_mode,) if args.flood_mode else FLOOD_MODES + CTL_MODES
    result = collect(args.quick, args.flood_only, flood_modes=modes, repeats=args.repeats, ctl_rate=args.node_ctl_rate,
                     transport_priority=args.transport_priority)  # fmt: skip
    if args.plot:
        plot_tracking(result["tracking"], args.plot)
    print(json.dumps(result, indent=1) if args.json else render(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
