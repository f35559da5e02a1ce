"""Hovers under sensor faults: the checks of the frame supervision and of the UKF's noise matching.

:func:`glitch_hover` flies the free scene's hover under a schedule of :mod:`omnirotor.experiments.faults`
(single bad frames, :func:`~omnirotor.experiments.faults.glitch_fault`), :func:`mocap_noise_hover` the ``hover``
task on a motion capture noisier than the UKF is told (SPEC §4.5 [A]). Used by ``tests/test_frame_supervision.py``,
``tests/test_mocap_noise_matching.py`` and ``tools/reliability_report.py``.
"""

from __future__ import annotations

import numpy as np

from omnirotor.control.admittance import AdmittanceParams
from omnirotor.control.controller import InteractionController
from omnirotor.control.trajectory import PoseTrajectory, Waypoint
from omnirotor.experiments.faults import install_faults
from omnirotor.experiments.loop import TaskOptions, run_closed_loop
from omnirotor.experiments.tasks import run_task
from omnirotor.experiments.tasks.common import ExperimentOptions
from omnirotor.sim import SimParams, Simulator
from omnirotor.vehicle import VehicleParams

__all__ = ["glitch_hover", "mocap_noise_hover"]


def glitch_hover(
    vehicle: VehicleParams, estimator: str, faults, duration_s: float, seed: int = 1, disturbances: bool = False
) -> dict:
    """Hover in the free scene under ``faults`` (e.g. :func:`glitch_fault` of sensor glitches).

    The compiled closed loop, free-flight admittance; the frame supervision's doing is in the returned logs.
    The plant is the undisturbed one unless ``disturbances``: the calibrated disturbances alone move the hover by
    up to about 5 cm (docs/fidelity.md), which would hide what a glitch does.

    Args:
        vehicle: the vehicle (plant and controller).
        estimator: "ukf" or "bypass".
        faults: the fault schedule.
        duration_s: length of the run [s].
        seed: the simulator's noise seed.
        disturbances: fly the simulator's calibrated disturbances too.

    Returns:
        ``t`` (k,) [s], ``err`` (k,) distance of the body from its hover reference [m], ``p_W`` (k, 3) the
        body's true position [m], ``status`` and
        ``cause`` (k,) the controller's status and frame-supervision bits, ``omega`` (k, n) the commands [Hz],
        ``sim`` (its fault schedule counted the commands) and ``ctl``.
    """
    params = TaskOptions(estimator=estimator).controller_params(AdmittanceParams.preset("free"))
    ctl = InteractionController(vehicle, params)
    sim_params = SimParams() if disturbances else SimParams().undisturbed()
    sim = install_faults(Simulator(vehicle, "free", sim_params, seed=seed), faults)
    p0, R0 = sim.default_start()
    traj = PoseTrajectory([Waypoint(0.0, p0 + R0 @ vehicle.p_E_B_array, R0)])
    clog, tlog = run_closed_loop(sim, ctl, traj, duration_s)
    return {
        "t": tlog.group("t").copy(),
        "err": np.linalg.norm(tlog.group("p_W") - p0, axis=1),
        "p_W": tlog.group("p_W").copy(),
        "status": clog.group("status").astype(np.int64),
        "cause": clog.group("frame_reject").astype(np.int64),
        "omega": clog.group("omega_cmd_hz").copy(),
        "sim": sim,
        "ctl": ctl,
    }


def mocap_noise_hover(true_m: float, told_m: float, matching: bool = True, seed: int = 0) -> tuple[float, dict]:
    """A 10 s hover (clean plant) on a motion capture of noise ``true_m`` whose UKF is told ``told_m`` [m].

    The check of the UKF's motion-capture noise matching (SPEC §4.5 [A], ``EstimatorParams.mocap_adapt_noise``;
    off without ``matching``), in ``tests/test_mocap_noise_matching.py`` and ``tools/reliability_report.py``.

    Returns:
        The largest per-axis RMS position error of the believed pose [cm] and the run's ``safety`` metrics.
    """
    overrides = [f"estimator.mocap_pos_std={told_m}"] + ([] if matching else ["estimator.mocap_adapt_noise=false"])
    options = ExperimentOptions(
        duration_s=10.0,
        disturbances=False,
        seed=seed,
        overrides=tuple(overrides),
        sim_overrides=(f"sensors.mocap_pos_noise_std={true_m}",),
    )
    m = run_task("hover", options).metrics
    return max(m["ee_rms_error"][k] for k in ("x_cm", "y_cm", "z_cm")), m["safety"]
