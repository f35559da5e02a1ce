"""ROS 2 bags in and out (issue 25 item 4): a bag of px4_msgs written by rosbags' own writer identifies as the
equivalent ULog does; a run written as a bag reads back with rosbags' reader and our type store."""

import json
import math

import numpy as np
import pytest

from conftest import SHARED
from omnirotor.cli import main

EVENTS = SHARED / "data" / "px4" / "sample_px4_events.ulg"


def _need(path):
    if not path.is_file():
        pytest.skip(f"PX4 test file not found at {path} (../shared is not beside the checkout)")
    return path


def _ulog_as_bag(ulog_path, bag, storage):
    """The ULog's attitude, local position, IMU and ESC topics as px4_msgs in a bag, by rosbags' Writer."""
    from pyulog import ULog
    from rosbags.rosbag2 import StoragePlugin, Writer

    from omnirotor.rosmsg import typestore

    ts = typestore()
    T = ts.types
    u = ULog(str(ulog_path))
    d = {x.name: x.data for x in u.data_list if x.multi_id == 0}

    def rows(name):
        return range(len(d[name]["timestamp"]))

    def f32(name, key, k):
        return np.float32(d[name][key][k])

    def attitude(k):
        q = np.array([d["vehicle_attitude"][f"q[{i}]"][k] for i in range(4)], dtype=np.float32)
        zero = np.zeros(4, dtype=np.float32)
        t = int(d["vehicle_attitude"]["timestamp"][k])
        return T["px4_msgs/msg/VehicleAttitude"](timestamp=t, timestamp_sample=t, q=q, delta_q_reset=zero,
                                                 quat_reset_counter=0)  # fmt: skip

    def local_position(k):
        lp = "vehicle_local_position"
        cls = T["px4_msgs/msg/VehicleLocalPosition"]
        values = {}
        for field, kind in cls.__dataclass_fields__.items():
            if field in d[lp] and kind.type in ("float", "int", "bool"):
                values[field] = {"float": float, "int": int, "bool": bool}[kind.type](d[lp][field][k])
            elif kind.type == "float":
                values[field] = 0.0
            elif kind.type == "int":
                values[field] = 0
            elif kind.type == "bool":
                values[field] = False
            elif field.startswith("delta_"):
                values[field] = np.zeros(2, dtype=np.float32)
        return cls(**values)

    def imu(k):
        sc = "sensor_combined"
        g = np.array([d[sc][f"gyro_rad[{i}]"][k] for i in range(3)], dtype=np.float32)
        a = np.array([d[sc][f"accelerometer_m_s2[{i}]"][k] for i in range(3)], dtype=np.float32)
        return T["px4_msgs/msg/SensorCombined"](timestamp=int(d[sc]["timestamp"][k]), gyro_rad=g, gyro_integral_dt=0,
                                                accelerometer_timestamp_relative=0, accelerometer_m_s2=a,
                                                accelerometer_integral_dt=0, accelerometer_clipping=0,
                                                gyro_clipping=0, accel_calibration_count=0,
                                                gyro_calibration_count=0)  # fmt: skip

    def esc(k):
        e = "esc_status"
        n = sum(1 for key in d[e] if key.endswith("].esc_rpm"))
        report = T["px4_msgs/msg/EscReport"]
        reports = []
        for i in range(n):
            values = {f: 0 if kind.type == "int" else 0.0 for f, kind in report.__dataclass_fields__.items()
                      if kind.type in ("int", "float")}  # fmt: skip
            values["esc_rpm"] = int(d[e][f"esc[{i}].esc_rpm"][k])
            reports.append(report(**values))
        reports += [report(**{f: 0 if v.type == "int" else 0.0 for f, v in report.__dataclass_fields__.items()
                             if v.type in ("int", "float")}) for _ in range(12 - n)]  # fmt: skip
        cls = T["px4_msgs/msg/EscStatus"]
        values = {f: 0 for f, kind in cls.__dataclass_fields__.items() if kind.type == "int"}
        values.update(timestamp=int(d[e]["timestamp"][k]), esc_count=n, esc=reports)
        return cls(**values)

    topics = [
        ("/fmu/out/vehicle_attitude", "VehicleAttitude", "vehicle_attitude", attitude),
        ("/fmu/out/vehicle_local_position", "VehicleLocalPosition", "vehicle_local_position", local_position),
        ("/fmu/out/sensor_combined", "SensorCombined", "sensor_combined", imu),
        ("/fmu/out/esc_status", "EscStatus", "esc_status", esc),
    ]
    plugin = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}[storage]
    with Writer(bag, version=9, storage_plugin=plugin) as w:
        for topic, kind, name, make in topics:
            msgtype = f"px4_msgs/msg/{kind}"
            conn = w.add_connection(topic, msgtype, typestore=ts)
            for k in rows(name):
                msg = make(k)
                w.write(conn, int(msg.timestamp) * 1000, ts.serialize_cdr(msg, msgtype))


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_px4_bag_by_rosbags_identifies_as_the_ulog(tmp_path, capsys, storage):
    ulog = _need(EVENTS)
    bag = tmp_path / "flight_bag"
    _ulog_as_bag(ulog, bag, storage)
    from omnirotor.identification import load_hover_data
    from omnirotor.vehicle import load_vehicle

    vehicle = load_vehicle(str(ulog))  # a bag stores no CA_* parameters: the ULog's vehicle, as --vehicle would
    from_ulog = load_hover_data([ulog], vehicle)
    from_bag = load_hover_data([bag], vehicle)
    assert from_bag.n_points == from_ulog.n_points == 1  # the steady descent
    np.testing.assert_allclose(from_bag.u_hz2, from_ulog.u_hz2, rtol=1e-9)
    np.testing.assert_allclose(from_bag.w_B, from_ulog.w_B, rtol=1e-9, atol=1e-12)
    capsys.readouterr()
    assert main(["identify", str(bag), "--vehicle", str(ulog), "--json"]) == 0
    rep_bag = json.loads(capsys.readouterr().out)
    assert main(["identify", str(ulog), "--json"]) == 0
    rep_ulog = json.loads(capsys.readouterr().out)
    assert math.isclose(rep_bag["global"]["force_residual_rms_N"], rep_ulog["global"]["force_residual_rms_N"],
                        rel_tol=1e-9)  # fmt: skip
    png = tmp_path / "w.png"
    assert main(["hover-windows", str(bag), "--vehicle", str(ulog), "--out", str(png)]) == 0
    assert "1 hover window(s)" in capsys.readouterr().out and png.is_file()


def test_bag_without_attitude_or_speeds_lists_both(tmp_path, capsys):
    from rosbags.rosbag2 import Writer

    from omnirotor.rosmsg import typestore

    ts = typestore()
    bag = tmp_path / "empty_bag"
    with Writer(bag, version=9) as w:
        conn = w.add_connection("/chatter", "std_msgs/msg/String", typestore=ts)
        for k in range(3):
            w.write(conn, k, ts.serialize_cdr(ts.types["std_msgs/msg/String"](data="x"), "std_msgs/msg/String"))
    assert main(["identify", str(bag), "--vehicle", "quadrotor"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no attitude" in err[0] and "no rotor speeds" in err[0]
