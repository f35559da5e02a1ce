"""The flight node's logic per 1 kHz period: the director, the recorder's copy, the live view; the writer's pace.

Run ``python benchmarks/bench_fly.py [--periods N] [--unpaced] [--json]``. Synthetic frames of a vehicle hovering
still (the real controller steps on them), one per millisecond; each figure is a distribution over the periods
(p50, p99, max in µs):

* ``director``: ``on_frame`` + ``wants_step`` + ``output`` (the controller's step not included; beside it for scale);
* ``recorder_copy``: :meth:`FlightRecorder.period` in the loop (the copy into the shared ring; recorded rows);
* ``live_view``: :meth:`LiveView.node_period` (at most one JSON message per period, 50 Hz per channel);
* ``writer``: rows per second the recorder's writer process turns into the bag (>= 1000 keeps up with 1 kHz).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))


def _pcts(samples_s: list[float]) -> dict[str, float]:
    us = np.array(samples_s) * 1e6
    return {"p50": float(np.percentile(us, 50)), "p99": float(np.percentile(us, 99)), "max": float(us.max())}


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--periods", type=int, default=20_000)
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--unpaced", action="store_true", help="As fast as possible instead of one period per ms.")
    args = ap.parse_args(argv)

    from omnirotor.fly.live import LiveView
    from omnirotor.fly.record import FlightRecorder
    from omnirotor.vehicle import load_vehicle
    from test_fly_director import _armed_in_hover  # a director armed and hovering on synthetic frames

    vehicle = load_vehicle("omnirotor")
    d, ctl, stream = _armed_in_hover(vehicle)
    ctl.log.ensure_capacity(args.periods + 10)
    frames = [stream.next() for _ in range(args.periods)]
    columns = ctl.log.column_names
    clock = time.perf_counter
    t_dir, t_ctl, t_rec, t_live = [], [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        rec = FlightRecorder(Path(tmp) / "bag", vehicle.n_rotors, columns)
        live = LiveView(port=0, log_columns=columns)
        t_start = clock()
        period = 0.0 if args.unpaced else 1e-3
        for k, (frame, ages) in enumerate(frames):
            while clock() < t_start + k * period:  # the node's pace: one frame per millisecond
                time.sleep(0.0002)
            a = clock()
            d.on_frame(frame, ages)
            step = d.wants_step()
            b = clock()
            cmd = ctl.step(frame) if step else None
            c = clock()
            out = d.output(cmd)
            e = clock()
            row = ctl.log.data[ctl.log.n - 1] if ctl.log.n else None
            recorded = rec.period(frame, out, 0, row)
            f = clock()
            live.node_period(frame, out, row)
            g = clock()
            t_dir.append((b - a) + (e - c))
            t_ctl.append(c - b)
            if recorded:
                t_rec.append(f - e)
            t_live.append(g - f)
        produced_s = clock() - t_start
        t_close = clock()
        summary = rec.close(timeout_s=600.0)
        drained_s = produced_s + (clock() - t_close)
        live.close()
    result = {
        "periods": args.periods,
        "director_us": _pcts(t_dir),
        "controller_step_us": _pcts(t_ctl),
        "recorder_copy_us": _pcts(t_rec),
        "live_view_us": _pcts(t_live),
        "writer_rows_per_s": summary["rows"] / drained_s,
        "recorder_dropped": summary["dropped"],
    }
    if args.json:
        print(json.dumps(result))
    else:
        for key in ("director_us", "controller_step_us", "recorder_copy_us", "live_view_us"):
            p = result[key]
            print(f"{key[:-3]:>18}: p50 {p['p50']:6.1f} µs  p99 {p['p99']:7.1f} µs  max {p['max']:8.1f} µs")
        print(
            f"{'writer':>18}: {result['writer_rows_per_s']:.0f} rows/s, "
            f"{summary['dropped']} of {args.periods} rows dropped"
        )
    return result


if __name__ == "__main__":
    main()
