"""The PX4 bridge's frame direction: what it costs and how late a frame reaches the node (issue 24 item 6).

``python benchmarks/bench_px4_bridge.py [--quick] [--json] [--cpu N --fifo-priority P]``: the stand-in PX4 of the tests
(``tests/sitl/fake_px4.py``: ``sensor_combined`` at 1 kHz, ESC telemetry and odometry at 100 Hz) and
``omnirotor px4-bridge --mocap odometry`` as processes on loopback Zenoh; this process subscribes to the node's
``/omnirotor/frame`` as the node would. Measured over the run after a warm-up:

* the bridge's CPU (its process, every thread: Zenoh's included) per IMU sample [µs] (one frame each: the frames
  the subscriber received in the measured span) and in % of a core;
* frames received per second, the IMU samples the bridge saw missing (``imu_gaps``), and its rate watch's gaps
  (no sample for 20 ms) with the worst, over its whole run;
* the age of a frame when it reaches the subscriber: its arrival on this host's monotonic clock minus the frame's
  ``t`` (the fake stamps each IMU sample with the same clock when it is due), p50/p99/max [µs]: PX4's sample to
  the node's frame, the stand-in's own lateness included (an upper bound of what the bridge adds).

``--cpu`` and ``--fifo-priority`` are passed to the bridge (its real-time options). The machine's load average
is reported with the figures. In this process, without the transport: one frame's encoding as the bridge did it
before (rosbags: the message refilled and serialised by the publisher) and as it does now (the in-place
``FrameEncoder``), µs per frame, the median of 5 rounds of 20 000 (``encode_us``).

Speed figures live here and in BENCHMARKS.md, never in the tests. Never part of the test suite.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))

from omnirotor.rosmsg.convert import FRAME  # noqa: E402
from omnirotor.transport import open_transport  # noqa: E402
from sitl.procs import CLI, env, free_port  # noqa: E402


def _cpu_s(pid: int) -> float:
    """User + system CPU time of a process [s] (/proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def bench_px4_bridge(seconds: float, warmup_s: float = 5.0, say=lambda line: print(line, file=sys.stderr),
                     bridge_args: tuple[str, ...] = ()) -> dict:  # fmt: skip
    """Run the stand-in PX4 and the bridge (with ``bridge_args``) for ``warmup_s + seconds`` of frames; the figures
    of the module docstring."""
    tmp = Path(tempfile.mkdtemp(prefix="bench-px4-bridge-"))
    px4_ep, test_ep = f"tcp/127.0.0.1:{free_port()}", f"tcp/127.0.0.1:{free_port()}"
    px4 = subprocess.Popen(
        [sys.executable, str(REPO / "tests" / "sitl" / "fake_px4.py"), px4_ep, "/px4", str(tmp), "--imu-hz", "1000",
         "--esc", "--odometry"], env=env(), stderr=subprocess.DEVNULL,
    )  # fmt: skip
    procs = [px4]
    try:
        with open_transport(listen=[test_ep], namespace="/bench") as t:
            frames = t.subscriber("/omnirotor/frame", FRAME, depth=1 << 14)
            bridge = subprocess.Popen(
                [sys.executable, "-c", CLI, "px4-bridge", "--connect", px4_ep, "--connect", test_ep,
                 "--namespace", "/bench", "--px4-namespace", "/px4", "--mocap", "odometry", "--json", *bridge_args],
                env=env(), stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
            )  # fmt: skip
            procs.append(bridge)
            say("bench_px4_bridge: waiting for the bridge's first frame (start-up, the IMU rate's second)")
            end = time.monotonic() + 120.0
            while frames.take(0.1) is None:
                if time.monotonic() > end or bridge.poll() is not None:
                    raise RuntimeError("the bridge published no frame")
            say(f"bench_px4_bridge: warm-up {warmup_s:g} s, then {seconds:g} s measured")
            end = time.monotonic() + warmup_s
            while time.monotonic() < end:
                frames.take(0.1)
            ages, n = [], 0
            c0, w0 = _cpu_s(bridge.pid), time.monotonic()
            end = w0 + seconds
            next_say = w0 + 5.0
            while (now := time.monotonic()) < end:
                m = frames.take(0.05)
                if m is not None:
                    ages.append(time.monotonic() - m.t)
                    n += 1
                if now >= next_say:
                    next_say += 5.0
                    say(f"bench_px4_bridge: {now - w0:.0f} s, {n} frames")
            c1, w1 = _cpu_s(bridge.pid), time.monotonic()
            bridge.send_signal(signal.SIGTERM)
            summary = json.loads(bridge.communicate(timeout=60)[0])
    finally:
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
                try:
                    p.wait(timeout=30)
                except subprocess.TimeoutExpired:
                    p.kill()
    age_us = 1e6 * np.array(ages)
    cpu = c1 - c0
    return {
        "seconds": w1 - w0,
        "frames_per_s": n / (w1 - w0),
        "bridge_cpu_percent": 100.0 * cpu / (w1 - w0),
        "bridge_cpu_us_per_imu_sample": 1e6 * cpu / max(n, 1),
        "frame_age_us": {k: float(np.percentile(age_us, q)) for k, q in (("p50", 50), ("p99", 99), ("max", 100))},
        "imu_gaps": summary["frames"]["imu_gaps"],
        "imu_watch": summary["frames"].get("imu_watch"),
        "esc_nan_frames": summary["frames"]["esc_nan_frames"],
        "frames_published": summary["frames"]["frames"],
        "loadavg": Path("/proc/loadavg").read_text().split()[:3],
    }


def bench_encode(rounds: int = 5, n: int = 20_000) -> dict:
    """µs per frame of the assembler's record encoded both ways (module docstring), the median of ``rounds``."""
    from omnirotor.fly.bridge import FrameAssembler
    from omnirotor.rosmsg.convert import FrameEncoder, WireMessages
    from omnirotor.transport.base import Publisher

    record = FrameAssembler(8).record
    record["t"] = 12.345
    enc, msgs = FrameEncoder(8), WireMessages(8)
    pub = Publisher(lambda payload, n_sent: None, FRAME, "bench")
    ways = {"rosbags": lambda k: pub.serialize(msgs.fill_frame(record, k)), "in_place": lambda k: enc.encode(record, k)}
    out = {}
    for name, encode in ways.items():
        times = []
        for _ in range(rounds):
            t0 = time.perf_counter()
            for k in range(n):
                encode(k)
            times.append(1e6 * (time.perf_counter() - t0) / n)
        out[name] = float(np.median(times))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="8 s measured instead of 30 s")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--cpu", type=int, help="the bridge's --cpu")
    ap.add_argument("--fifo-priority", type=int, help="the bridge's --fifo-priority")
    a = ap.parse_args()
    extra = [] if a.cpu is None else ["--cpu", str(a.cpu)]
    extra += [] if a.fifo_priority is None else ["--fifo-priority", str(a.fifo_priority)]
    r = bench_px4_bridge(8.0 if a.quick else 30.0, bridge_args=tuple(extra))
    r["encode_us"] = bench_encode()
    if a.json:
        print(json.dumps(r))
        return
    age = r["frame_age_us"]
    print(
        f"frames {r['frames_per_s']:.0f}/s over {r['seconds']:.0f} s; bridge CPU {r['bridge_cpu_percent']:.0f} % of "
        f"a core = {r['bridge_cpu_us_per_imu_sample']:.0f} µs per IMU sample; frame age at the node p50 "
        f"{age['p50']:.0f} / p99 {age['p99']:.0f} / max {age['max']:.0f} µs; IMU samples lost {r['imu_gaps']}, "
        f"frames without ESC speeds {r['esc_nan_frames']}"
        + (f"; gaps > 20 ms {w['gaps']} (worst {w['worst_gap_ms']:.0f} ms)" if (w := r["imu_watch"]) else "")
        + f"; load {' '.join(r['loadavg'])}"
    )
    e = r["encode_us"]
    print(f"one frame's encoding: rosbags {e['rosbags']:.1f} µs, in place {e['in_place']:.1f} µs")


if __name__ == "__main__":
    main()
