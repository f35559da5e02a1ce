"""The compiled paths of the 1 kHz loop against independent references.

The controller's compiled step has no Python twin any more; its numbers are pinned to the recorded
reference of the code before the change (``tests/test_controller_reference.py``). Here:

* the same composer with the QP solved by daqp from Python (between its two compiled halves) flies the
  slide over the pipe (contact, map switches, UKF and bypass, a failed rotor) as the compiled QP does: the
  same commands to the solvers' precision, the same statuses and regions;
* an estimate given from Python (any estimator the compiled step does not run) gives the compiled
  estimator's numbers bit for bit, when it is the same estimate;
* the compiled closed loop (``experiments._loop.run_steps``, in chunks between progress reports) against the
  Python loop of ``run_closed_loop``: both logs and the final simulator state;
* the QP-failure fallback against NumPy's pseudo-inverse (an independent oracle).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from omnirotor.control import composer as _c
from omnirotor.control.allocation import AllocationParams, Allocator
from omnirotor.control.controller import ControllerParams, InteractionController
from omnirotor.control.estimator import EstimatorParams
from omnirotor.control.maps import MapParams
from omnirotor.control.trajectory import PoseTrajectory
from omnirotor.experiments.faults import MocapDropout, SensorCorruption, install_faults
from omnirotor.experiments.loop import run_closed_loop
from omnirotor.regions import load_partition
from omnirotor.sim import SimParams, Simulator
from omnirotor.vehicle import load_vehicle

sys.path.insert(0, str(Path(__file__).parent / "reference"))

from record_controller import maps, slide  # noqa: E402 (the same slide and maps as the recorded reference)

V = load_vehicle("omnirotor")
PARTITION = load_partition("paper")


def _slide(sim: Simulator) -> PoseTrajectory:
    """Approach the pipe, touch it, slide over it to 45 deg of roll (across the R1/R3 border at 30 deg)."""
    return slide(sim.scene.pipe_centre_W, sim.scene.pipe_radius)


def _setup(estimator: str, mode: str, blend: str = "hard", failed: int | None = None, solver: str = "active-set"):
    sim = Simulator(V, "pipe", SimParams().undisturbed(), seed=5)  # solvers compared on a clean plant
    params = ControllerParams(
        estimator=EstimatorParams(kind=estimator),
        maps=MapParams(mode=mode, blend=blend, blend_width_deg=10.0),
        allocation=AllocationParams(solver=solver),
    )
    ctl = InteractionController(V, params, maps=maps() if mode != "nominal" else None)
    if failed is not None:
        mask = np.zeros(V.n_rotors, dtype=bool)
        mask[failed] = True
        ctl.set_failed_rotors(mask)
    return sim, ctl, _slide(sim)


CASES = [
    ("ukf", "piecewise", "hard", None),
    ("bypass", "piecewise", "smooth", None),
    ("ukf", "nominal", "hard", 2),
]


def _fly(sim, ctl, traj, duration, wrap=None):
    """A hand-written loop of the simulator and the controller (``wrap``: wrap its estimator after the reset,
    e.g. in a stand-in the compiled step does not know)."""
    plant = sim
    p0 = traj.waypoints[0].p_W - traj.waypoints[0].R_WB @ V.p_E_B_array
    frame = plant.reset(p_W=p0, R_WB=traj.waypoints[0].R_WB)
    ctl.log.ensure_capacity(int(round(duration / ctl.params.dt)))
    ctl.reset(frame, traj)
    if wrap is not None:
        ctl.estimator = wrap(ctl.estimator)
    cmd = ctl.hold_command()
    statuses, regions = [], []
    row = np.zeros(64)
    contact_steps = 0
    for _ in range(int(round(duration / ctl.params.dt))):
        frame = plant.step(cmd)
        cmd = ctl.step(frame)
        statuses.append(int(cmd.status))
        regions.append(ctl.scheduler.region_index)
        sim.truth_row(row)
        contact_steps += row[28] > 0.5  # the contact flag of the truth row
    return np.array(statuses), np.array(regions), contact_steps


@pytest.mark.parametrize(("estimator", "mode", "blend", "failed"), CASES)
def test_composer_with_a_python_qp_solver_flies_as_the_compiled_one(estimator, mode, blend, failed):
    runs = []
    for solver in ("active-set", "daqp"):
        sim, ctl, traj = _setup(estimator, mode, blend, failed, solver)
        assert (ctl.allocator.kernel_backend is None) == (solver == "daqp")
        statuses, regions, contact_steps = _fly(sim, ctl, traj, 3.4)
        runs.append((ctl.log.group("omega_cmd_hz").copy(), statuses, regions, contact_steps, ctl.allocator))
    (cmd_c, st_c, reg_c, contact_c, al_c), (cmd_d, st_d, reg_d, _, al_d) = runs
    # Both solvers are exact active-set methods: the same optimum to rounding, hence the same flight. Compared
    # in the QP's variable u = w|w| [Hz²]: near a zero crossing w = sign(u)|u|^(1/2) magnifies a rounding-level
    # difference of u (the former 1e-6 Hz is 2.7e-4 Hz² at the hover speed 136 Hz: 1e-4 Hz² is tighter there).
    np.testing.assert_allclose(cmd_d * np.abs(cmd_d), cmd_c * np.abs(cmd_c), rtol=0.0, atol=1e-4)
    np.testing.assert_array_equal(st_c, st_d)
    np.testing.assert_array_equal(reg_c, reg_d)
    assert (al_c.n_fallbacks, al_c.n_nonfinite) == (al_d.n_fallbacks, al_d.n_nonfinite)
    # The run did what it is meant to cover: contact with the pipe, and the map switch in piecewise mode.
    assert contact_c > 500
    if mode == "piecewise":
        assert {PARTITION.names.index("R1"), PARTITION.names.index("R3")} <= set(reg_c.tolist())
    if failed is not None:
        assert np.all(st_c & int(_c._BIT_EXCLUDED))


class _Relay:
    """An estimator the compiled step does not know, passing another one's estimates through unchanged."""

    def __init__(self, inner):
        self.inner = inner

    def __getattr__(self, name):
        return getattr(self.inner, name)

    def reset(self, frame):
        self.inner.reset(frame)

    def step(self, frame):
        return self.inner.step(frame)


@pytest.mark.parametrize("estimator", ["ukf", "bypass"])
def test_an_estimate_given_from_python_gives_the_compiled_numbers(estimator):
    faults = [
        SensorCorruption(signal="imu_gyro", kind="nan", t_start_s=0.5, duration_s=0.004),
        MocapDropout(t_start_s=0.8, duration_s=0.3),
    ]
    runs = []
    for wrap in (None, _Relay):
        sim, ctl, traj = _setup(estimator, "piecewise")
        install_faults(sim, faults)
        statuses, _, _ = _fly(sim, ctl, traj, 1.5, wrap=wrap)
        assert ctl.kernel_state is None if wrap else ctl.kernel_state is not None
        runs.append((ctl.log.data[: ctl.log.n].copy(), statuses, ctl.frame_causes))
    np.testing.assert_array_equal(runs[0][0], runs[1][0])
    np.testing.assert_array_equal(runs[0][1], runs[1][1])
    # The frame supervision runs in both (the estimator run from Python reads the raw frame and replaces the bad
    # gyroscope sample itself, as the supervision does for the compiled one: the same numbers).
    assert runs[0][2] == runs[1][2] and runs[0][2]["imu"] == 4
    if estimator == "ukf":
        assert np.count_nonzero(runs[0][1] & int(_c._BIT_DEGRADED)) > 10


@pytest.mark.parametrize(("estimator", "mode", "blend", "failed"), CASES)
def test_compiled_closed_loop_equals_the_python_loop(estimator, mode, blend, failed):
    runs = []
    for compiled in (True, False):
        sim, ctl, traj = _setup(estimator, mode, blend, failed)
        ticks: list[float] = []
        # A no-op on_step makes run_closed_loop take its Python loop.
        hook = None if compiled else (lambda s, t: None)
        clog, tlog = run_closed_loop(sim, ctl, traj, 3.4, progress=ticks.append, on_step=hook)
        runs.append((clog, tlog, sim, ctl, ticks))
    (c1, t1, s1, k1, ticks1), (c2, t2, s2, k2, _) = runs
    assert c1.n == c2.n == t1.n == t2.n == 3400
    np.testing.assert_array_equal(c1.data[: c1.n], c2.data[: c2.n])
    timing = t1.n_signals - 2  # the last two columns, the wall-clock times of both steps, differ of course
    np.testing.assert_array_equal(t1.data[: t1.n, :timing], t2.data[: t2.n, :timing])
    np.testing.assert_array_equal(s1.data.qpos, s2.data.qpos)
    assert s1.t == s2.t and s1.step_index == 3400
    assert k1.scheduler.region_index == k2.scheduler.region_index
    assert k1.scheduler.region_name == k2.scheduler.region_name
    assert np.all(t1.data[: t1.n, timing:] > 0.0)  # every compiled step was timed, the plant's and the controller's
    assert ticks1[-1] == 1.0 and len(ticks1) >= 50 and ticks1 == sorted(ticks1)
    assert np.any(t1.group("in_contact") > 0.5)


def test_fallback_is_the_clipped_pseudo_inverse():
    rng = np.random.default_rng(1)
    alloc = Allocator(V)
    scale = alloc.state["u_scale_hz2"][0]
    for failed in (None, 4):
        mask = np.zeros(V.n_rotors, dtype=bool)
        if failed is not None:
            mask[failed] = True
        alloc.set_failed_rotors(mask)
        alloc.solve(rng.normal(0.0, 3.0, 6) + [0, 0, 14, 0, 0, 0], np.eye(3), V.A_nom)
        before = alloc.n_fallbacks
        alloc._backend.max_iter = 0  # the QP fails: the allocator falls back
        w_ref = rng.normal(0.0, 3.0, 6) + [0, 0, 14, 0, 0, 0]
        u = alloc.solve(w_ref, np.eye(3), V.A_nom).copy()
        alloc._backend.max_iter = AllocationParams().max_iter
        As = np.where(mask, 0.0, V.A_nom * scale)
        x = np.clip(np.linalg.pinv(As) @ w_ref, alloc.arrays.lo, alloc.arrays.hi)
        np.testing.assert_allclose(u, x * scale, rtol=1e-12, atol=1e-12 * np.abs(x * scale).max())
        assert alloc.n_fallbacks == before + 1 and int(alloc.status) == 1
        if failed is not None:
            assert u[failed] == 0.0
