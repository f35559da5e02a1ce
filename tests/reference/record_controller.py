"""Record the controller reference replayed by ``tests/test_controller_reference.py``.

Flies the slide over the pipe of ``tests/test_compiled_loop.py`` (simulator in the loop) in four set-ups and
stores, for each, the packed sensor frames the controller received and a digest of everything it produced
(log rows, statuses, region indices, counters), plus every 50th log row to locate a difference. The test then
feeds the stored frames to the controller of the code under test through its public ``step`` and requires
the same digest: the controller's numbers, bit for bit, independent of the simulator.

Run from the checkout root (it was run on the commit before the architecture change of issue 11)::

    PYTHONPATH=$PWD/src python tests/reference/record_controller.py tests/data/controller_reference.npz
"""

from __future__ import annotations

import hashlib
import math
import sys

import numpy as np

from omnirotor.control.controller import ControllerParams, InteractionController
from omnirotor.control.estimator import EstimatorParams
from omnirotor.control.maps import MapParams
from omnirotor.control.trajectory import PoseTrajectory, Waypoint
from omnirotor.messages import SensorFrame, StateEstimate
from omnirotor.regions import load_partition
from omnirotor.so3 import rot_x
from omnirotor.vehicle import load_vehicle
from omnirotor.wrench_maps import MapEntry, WrenchMapSet

V = load_vehicle("omnirotor")
PARTITION = load_partition("paper")

# name: (estimator, map mode, blend, failed rotor, corrupted frames, duration [s])
CASES = {
    "ukf_piecewise_hard": ("ukf", "piecewise", "hard", -1, False, 3.4),
    "bypass_piecewise_smooth": ("bypass", "piecewise", "smooth", -1, False, 3.4),
    "ukf_nominal_failed2": ("ukf", "nominal", "hard", 2, False, 3.4),
    "ukf_piecewise_corrupted": ("ukf", "piecewise", "hard", -1, True, 2.5),
}
EVERY = 50

# The stored frames' flat layout (the packed frame of the code the reference was recorded with): time,
# accelerometer (3), gyroscope (3), motion-capture flag, time, position (3), quaternion (4), state flag, state
# (p_W, v_W, a_W, R_WB row-major, omega_B: 21), rotor speeds (n).
_T, _ACC, _GYRO, _MOCAP, _STATE_FLAG, _STATE, _ROTOR = 0, 1, 4, 7, 16, 17, 38


def flat_size(n_rotors: int) -> int:
    """Entries of a stored frame."""
    return _ROTOR + n_rotors


def frame_of_flat(b: np.ndarray) -> SensorFrame:
    """The :class:`SensorFrame` of a stored flat frame."""
    b = np.array(b, dtype=float)
    t = float(b[_T])
    state = None
    if b[_STATE_FLAG] != 0.0:
        x = b[_STATE : _STATE + 21]
        state = StateEstimate(t, x[0:3], x[3:6], x[6:9], x[9:18].reshape(3, 3), x[18:21])
    acc, gyro, rotor = b[_ACC : _ACC + 3], b[_GYRO : _GYRO + 3], b[_ROTOR:]
    m = _MOCAP
    if b[m] == 0.0:
        return SensorFrame(t, acc, gyro, rotor, False, 0.0, None, None, state)
    return SensorFrame(t, acc, gyro, rotor, True, float(b[m + 1]), b[m + 2 : m + 5], b[m + 5 : m + 9], state)


def flat_of_frame(frame: SensorFrame, out: np.ndarray) -> None:
    """Write ``frame`` into a stored flat frame ``out`` (the inverse of :func:`frame_of_flat`)."""
    out[:] = 0.0
    out[_T] = frame.t
    out[_ACC : _ACC + 3], out[_GYRO : _GYRO + 3], out[_ROTOR:] = frame.imu_acc_B, frame.imu_gyro_B, frame.rotor_hz
    if frame.mocap_new:
        m = _MOCAP
        out[m], out[m + 1] = 1.0, frame.mocap_t
        out[m + 2 : m + 5], out[m + 5 : m + 9] = frame.mocap_p_W, frame.mocap_q_WB
    s = frame.state
    if s is not None:
        out[_STATE_FLAG] = 1.0
        out[_STATE : _STATE + 21] = np.r_[s.p_W, s.v_W, s.a_W, np.ravel(s.R_WB), s.omega_B]


def maps(seed: int = 3) -> WrenchMapSet:
    """A different map in every region (force rows scaled by 1.0 ... 1.2), so that every switch matters."""
    rng = np.random.default_rng(seed)
    regions = {
        name: MapEntry(A=V.A_nom * np.r_[rng.uniform(1.0, 1.2, 3), np.ones(3)][:, None], points=10, identified=True)
        for name in PARTITION.names
    }
    return WrenchMapSet(vehicle="omnirotor", nominal=V.A_nom, partition=PARTITION, regions=regions)


def slide(pipe_centre_W, pipe_radius: float) -> PoseTrajectory:
    """Approach the pipe, touch it, slide over it to 45 deg of roll (across the R1/R3 border at 30 deg)."""
    c, r = np.asarray(pipe_centre_W), pipe_radius - 0.01
    th = math.radians(45.0)
    touch = c + np.array([0.0, -r, 0.0])
    apex = c + np.array([0.0, -r * math.cos(th), r * math.sin(th)])
    R0 = np.eye(3)
    return PoseTrajectory(
        [
            Waypoint(0.0, touch - [0.0, 0.08, 0.0], R0),
            Waypoint(1.0, touch, R0),
            Waypoint(1.4, touch, R0),
            Waypoint(3.4, apex, rot_x(-th)),
        ]
    )


def controller(estimator: str, mode: str, blend: str, failed: int, params=None) -> InteractionController:
    """The controller of a case (``params``: other ControllerParams fields, e.g. another observer)."""
    params = ControllerParams(
        estimator=EstimatorParams(kind=estimator),
        maps=MapParams(mode=mode, blend=blend, blend_width_deg=10.0),
        **(params or {}),
    )
    ctl = InteractionController(V, params, maps=maps() if mode != "nominal" else None)
    if failed >= 0:
        mask = np.zeros(V.n_rotors, dtype=bool)
        mask[failed] = True
        ctl.set_failed_rotors(mask)
    return ctl


def digest(ctl: InteractionController, statuses, regions, width: int | None = None) -> tuple[str, np.ndarray]:
    """SHA-256 of the log, statuses, regions and counters; and every ``EVERY``-th log row.

    ``width``: only the first ``width`` columns of the log (the layout a reference was recorded with; columns
    added to the log since are checked by the test itself).
    """
    a, e = ctl.allocator, ctl.estimator
    counters = np.array(
        [a.n_fallbacks, a.n_nonfinite, int(a.status), a.saturated, e.rejected_inputs, e.degraded], dtype=np.int64
    )
    log = np.ascontiguousarray(ctl.log.data[: ctl.log.n, :width])
    h = hashlib.sha256()
    for arr in (log, np.asarray(statuses, dtype=np.int64), np.asarray(regions, dtype=np.int64), counters):
        h.update(np.ascontiguousarray(arr).tobytes())
    return h.hexdigest(), log[::EVERY].copy()


def record(out: str) -> None:
    from omnirotor.experiments.faults import MocapDropout, SensorCorruption, install_faults
    from omnirotor.sim import SimParams, Simulator

    data = {}
    for name, (estimator, mode, blend, failed, corrupted, duration) in CASES.items():
        sim = Simulator(V, "pipe", SimParams(), seed=5)
        plant = sim
        if corrupted:
            install_faults(
                sim,
                [
                    SensorCorruption(signal="imu_gyro", kind="nan", t_start_s=0.5, duration_s=0.004),
                    SensorCorruption(signal="mocap", kind="nan", t_start_s=0.8, duration_s=0.03),
                    SensorCorruption(signal="rotor_hz", kind="inf", t_start_s=1.1, duration_s=0.003),
                    MocapDropout(t_start_s=1.5, duration_s=0.3),
                ],
            )
        ctl = controller(estimator, mode, blend, failed)
        traj = slide(sim.scene.pipe_centre_W, sim.scene.pipe_radius)
        steps = int(round(duration / ctl.params.dt))
        p0 = traj.waypoints[0].p_W - traj.waypoints[0].R_WB @ V.p_E_B_array
        frame = plant.reset(p_W=p0, R_WB=traj.waypoints[0].R_WB)
        frames = np.zeros((steps + 1, flat_size(V.n_rotors)))
        flat_of_frame(frame, frames[0])
        ctl.log.ensure_capacity(steps)
        ctl.reset(frame, traj)
        cmd = ctl.hold_command()
        statuses, regions = [], []
        for k in range(steps):
            frame = plant.step(cmd)
            flat_of_frame(frame, frames[k + 1])
            cmd = ctl.step(frame)
            statuses.append(int(cmd.status))
            regions.append(ctl.scheduler.region_index)
        h, rows = digest(ctl, statuses, regions)
        data[f"{name}/frames"] = frames
        data[f"{name}/digest"] = np.array(h)
        data[f"{name}/rows"] = rows
        data[f"{name}/pipe"] = np.r_[sim.scene.pipe_centre_W, sim.scene.pipe_radius]
        print(name, h, int(np.count_nonzero(np.asarray(statuses))), "flagged steps")
    np.savez_compressed(out, **data)


if __name__ == "__main__":
    record(sys.argv[1])
