"""Flight recording: a writer process streams a ROS 2 bag (MCAP) in bounded memory; it reads back with rosbags,
the project's reader and the mcap library (what Foxglove opens)."""

import math
from pathlib import Path

import numpy as np
import pytest

from omnirotor.control.controller import LOG_GROUPS
from omnirotor.errors import InputError
from omnirotor.fly.modes import FlightMode
from omnirotor.fly.record import TOPICS, FlightRecorder, read_recording
from omnirotor.fly.requests import FlightStatus
from omnirotor.messages import SensorFrame
from omnirotor.recorder import Recorder

COLUMNS = Recorder(1, LOG_GROUPS(8)).column_names
SESSION = 0xF00DFACE12345679  # the plant's session, recorded with its frames


def _frame(k, mocap_every=10):
    t = k * 1e-3
    mocap = k % mocap_every == 0
    p_W, q_WB = np.array([0.0, 0.0, 1.0 + 1e-6 * k]), np.array([1.0, 0.0, 0.0, 0.0])
    acc, gyro = np.array([0.0, 0.0, 9.81]), np.array([0.0, 0.0, 0.01 * k])
    return SensorFrame(t, acc, gyro, np.full(8, 140.0 + k % 7), mocap, t - 0.004, p_W, q_WB)


def _log_row(k):
    row = np.zeros(len(COLUMNS))
    for g in ("R_WB", "R_E_ref", "R_E_des"):
        for a in ("xx", "yy", "zz"):
            row[COLUMNS.index(f"{g}.{a}")] = 1.0
    row[COLUMNS.index("p_W.z")] = 1.0 + 1e-6 * k
    row[COLUMNS.index("f_ext_W.y")] = -3.0
    row[COLUMNS.index("m_ext_B.z")] = 0.5
    return row


def _status(t):
    return FlightStatus(t, FlightMode.HOLD, 0, 0, 0, "free", "nominal", 0.0, None, 1, 1, 0, 0, 0, 0, "arrived: hold")


def _rss_kb(pid):
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return 0


def test_a_recording_reads_back_with_rosbags_and_the_mcap_library(tmp_path):
    path = tmp_path / "flight"
    with FlightRecorder(path, 8, COLUMNS, derived_every=5) as rec:
        for k in range(1000):
            assert rec.period(_frame(k), np.full(8, 150.0 + k % 3), 4, _log_row(k), block=True, plant_session=SESSION)
            if k % 20 == 0:
                rec.status(_status(k * 1e-3))
    r = read_recording(path)
    assert r.counts["/omnirotor/frame"] == r.counts["/omnirotor/rotor_cmd"] == 1000
    assert r.counts["/omnirotor/pose"] == r.counts["/omnirotor/wrench_est"] == 200  # every 5th period
    assert r.counts["/omnirotor/status"] == 50 and r.status[0].mode == FlightMode.HOLD
    np.testing.assert_array_equal(r.t, np.arange(1000) * 1e-3)  # float64 time, exact
    assert r.plant_session.dtype == np.uint64 and (r.plant_session == SESSION).all()  # all 64 bits
    np.testing.assert_array_equal(r.cmd_hz[:, 0], 150.0 + np.arange(1000) % 3)
    np.testing.assert_array_equal(r.rotor_hz[:, 3], 140.0 + np.arange(1000) % 7)
    assert r.mocap_new.sum() == 100 and (r.control_status == 4).all()
    np.testing.assert_allclose(r.p_W[:, 2], 1.0 + 1e-6 * np.arange(0, 1000, 5))
    np.testing.assert_array_equal(r.f_ext_W[0], [0.0, -3.0, 0.0])
    # The .mcap inside is what Foxglove opens: ros2msg schemas and CDR messages on every topic.
    from mcap.reader import make_reader

    (mcap_file,) = path.glob("*.mcap")
    with mcap_file.open("rb") as fh:
        summary = make_reader(fh).get_summary()
    channels = {c.topic: c for c in summary.channels.values()}
    assert set(channels) == set(TOPICS)
    assert {summary.schemas[c.schema_id].encoding for c in channels.values()} == {"ros2msg"}
    assert {c.message_encoding for c in channels.values()} == {"cdr"}


def test_a_long_recording_streams_in_bounded_memory(tmp_path):
    """A minute at 1 kHz: the writer's memory stays flat between 10 s and 60 s (nothing caps the duration)."""
    path = tmp_path / "long"
    n = 60_000
    rec = FlightRecorder(path, 8, COLUMNS)
    row = _log_row(0)
    rss = {}
    for k in range(n):
        rec.period(_frame(k), np.full(8, 150.0), 0, row, block=True)
        if k in (10_000, n - 1):
            rss[k] = _rss_kb(rec.writer_pid)
    mcap_size_mid = sum(f.stat().st_size for f in path.glob("*.mcap"))
    summary = rec.close(timeout_s=120.0)
    assert summary["rows"] == n and summary["dropped"] == 0
    assert summary["messages"]["/omnirotor/frame"] == n
    size = sum(f.stat().st_size for f in path.glob("*.mcap"))
    assert size > 10e6 and mcap_size_mid > 0.8 * size  # streamed to disk while recording, not at the end
    assert rss[n - 1] - rss[10_000] < 4_000, rss  # kB: the chunk-index entries, not the 50 s of data
    r = read_recording(path)
    assert r.t.size == n and r.t[-1] == pytest.approx(59.999)


def test_a_full_ring_drops_rows_and_counts_them_never_blocks(tmp_path):
    rec = FlightRecorder(tmp_path / "small", 8, (), capacity=4)
    results = [rec.period(_frame(k), np.zeros(8)) for k in range(200)]  # far faster than the writer drains
    summary = rec.close()
    assert summary["dropped"] == results.count(False) > 0
    assert summary["rows"] == results.count(True) == read_recording(tmp_path / "small").t.size


def test_bad_paths_are_refused_in_one_line(tmp_path):
    (tmp_path / "exists").mkdir()
    with pytest.raises(InputError, match="exists already"):
        FlightRecorder(tmp_path / "exists", 8)
    with pytest.raises(InputError, match="does not exist"):
        FlightRecorder(tmp_path / "no" / "bag", 8)
    with pytest.raises(InputError, match="not a readable flight recording"):
        read_recording(tmp_path / "exists")
    assert math.isfinite(_status(0.0).t)
