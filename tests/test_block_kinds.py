"""Proof of the block contract for every controller kind (issue 23 item 3): a new block of each kind, defined in
this file alone and registered with one line, flies the hover through the public API inside the controller's one
compiled step, chosen by name in ``ControllerParams`` (the observer's variant is in tests/test_observer_variant.py;
the estimators are the package's two, UKF and bypass, reached the same way).

* "test-rigid" admittance never yields: the compliant reference is the desired one, its offset stays zero;
* "test-counting" pose controller is the geometric PID of SPEC §4.1 (the package's ``pose_step``) plus a step
  counter that it logs: the flight is bit for bit the default one, and the counter says its kernel ran;
* "test-pass" supervisor passes every frame through unchecked and counts them, "test-fixed" maps keep the
  nominal map (and count their calls), "test-constant" trajectory holds its last waypoint's pose (and counts its
  samples): on the clean hover, where the default supervision rejects nothing, the flight is bit for bit the
  default one;
* "test-least-squares" allocation is the minimum-norm inverse of the map, clipped, with no QP: its inputs are
  that inverse of the logged wrench reference, and it holds the hover.
"""

import numba
import numpy as np

from omnirotor.blocks import CONTROLLER_KINDS, KIND_STEPS, block_class, block_names, register, state_array
from omnirotor.control.allocation import ALLOC_DONE, BEGIN_HELD
from omnirotor.control.controller import ControllerParams, InteractionController
from omnirotor.control.estimator import EstimatorParams
from omnirotor.control.pose import STATE_DTYPE as POSE_DTYPE
from omnirotor.control.pose import PoseController, pose_step
from omnirotor.control.supervisor import N_CAUSES
from omnirotor.control.trajectory import PoseTrajectory, Waypoint
from omnirotor.experiments.loop import run_closed_loop
from omnirotor.frame_kernels import copy_head
from omnirotor.messages import FRAME_HEAD_DTYPE
from omnirotor.sim import SimParams, Simulator
from omnirotor.sim.params import AeroParams
from omnirotor.vehicle import load_vehicle

F8 = np.float64
RIGID_DTYPE = np.dtype([("xi_p_W", F8, 3), ("n_nonfinite", F8), ("n_steps", F8), ("f_E_W", F8, 3)])


@numba.njit(cache=False)
def rigid_step(r, f_E_W, m_E_W, desired, compliant, dt):
    """The compliant reference is the desired one (no offset); the EE force is kept for the record."""
    for i in range(3):
        compliant.p_W[i] = desired.p_W[i]
        compliant.v_W[i] = desired.v_W[i]
        compliant.a_W[i] = desired.a_W[i]
        compliant.omega_W[i] = desired.omega_W[i]
        compliant.alpha_W[i] = desired.alpha_W[i]
        r.f_E_W[i] = f_E_W[i]
        for j in range(3):
            compliant.R_WB[i, j] = desired.R_WB[i, j]
    r.n_steps += 1.0


@register("admittance", "test-rigid")
class RigidAdmittance:
    state_dtype = RIGID_DTYPE
    log_fields = ("xi_p_W", ("f_E_seen_W", ("f_E_W",)))
    kernel = rigid_step

    def __init__(self, params, *, state=None):
        self.state = state_array(RIGID_DTYPE, state, "rigid admittance")
        self.params = params

    def set_params(self, params):
        self.params = params

    def reset(self):
        self.state[...] = np.zeros(1, RIGID_DTYPE)


COUNTING_DTYPE = np.dtype([("n_steps", F8), *((name, POSE_DTYPE.fields[name][0]) for name in POSE_DTYPE.names)])


@numba.njit(cache=False)
def counting_pose_step(r, body_ref, p_W, v_W, R_WB, omega_B, f_filt_W, m_filt_B, dt):
    pose_step(r, body_ref, p_W, v_W, R_WB, omega_B, f_filt_W, m_filt_B, dt)
    r.n_steps += 1.0


@register("pose", "test-counting")
class CountingPose:
    state_dtype = COUNTING_DTYPE
    log_fields = (*PoseController.log_fields, ("pose_steps", ("n_steps",)))
    log_labels = PoseController.log_labels
    kernel = counting_pose_step

    def __init__(self, vehicle, params, *, state=None):
        self.state = state_array(COUNTING_DTYPE, state, "counting pose")
        self._inner = PoseController(vehicle, params)  # its parameters, written into this record
        for name in POSE_DTYPE.names:
            self.state[name] = self._inner.state[name]

    def reset(self):
        for name in ("f_ref_W", "m_ref_B", "errors", "e_i_W", "n_nonfinite", "n_steps"):
            self.state[name] = 0.0


PASS_DTYPE = np.dtype(
    [
        # the supervisor kind's outputs (KIND_STEPS)
        ("clean", FRAME_HEAD_DTYPE),
        ("cause", np.int64),
        ("counts", np.int64, N_CAUSES),
        ("dt_s", F8),
        ("coasting", np.int64),
        ("blind", np.int64),
        ("reinit_v_W", F8, 3),
        ("fs_mode", np.int64),
        # its own
        ("dt_nom", F8),
        ("n_frames", F8),
        ("n_nonfinite", F8),
    ]
)


@numba.njit(cache=False)
def pass_supervise(r, frame, estimate):
    """Every frame as received (no check), each closing one period; counted."""
    copy_head(frame, r.clean)
    r.dt_s = r.dt_nom
    r.n_frames += 1.0
    return 0


@register("supervisor", "test-pass")
class PassSupervisor:
    state_dtype = PASS_DTYPE
    log_fields = (("frames_seen", ("n_frames",)),)
    kernel = pass_supervise  # no failsafe: no entry "reference"

    def __init__(self, vehicle, params, *, state=None):
        self.state = state_array(PASS_DTYPE, state, "pass-through supervisor")

    def reset(self, frame, *, dt, acc_range, gyro_range, check_state, check_mocap):
        self.state[...] = np.zeros(1, PASS_DTYPE)
        self.state["dt_nom"] = dt


FIXED_DTYPE = np.dtype([("region", np.int64), ("n_calls", F8), ("n_nonfinite", F8)])


@numba.njit(cache=False)
def fixed_select(r, arrays, R_WB):
    """The map stays the one written at construction (arrays.out); no region; counted."""
    r.n_calls += 1.0
    r.region = -1
    return -1


@register("maps", "test-fixed")
class FixedMaps:
    state_dtype = FIXED_DTYPE
    log_fields = (("map_calls", ("n_calls",)),)
    kernel = fixed_select
    follows_attitude = True  # its kernel runs every period

    def __init__(self, vehicle, maps, params, *, state=None, arrays=None):
        self.state = state_array(FIXED_DTYPE, state, "fixed maps")
        arrays[0]["out"][:] = vehicle.A_nom  # the controller's maps_arrays.out, (6, n)

    def reset(self):
        self.state["n_calls"] = 0.0

    def sync(self):
        """No region name to follow."""


CONSTANT_DTYPE = np.dtype([("p_W", F8, 3), ("R_WB", F8, (3, 3)), ("n_samples", F8), ("n_nonfinite", F8)])


@numba.njit(cache=False)
def constant_sample(r, data, t, ref):
    """The pose held at rest, whatever the time."""
    for i in range(3):
        ref.p_W[i] = r.p_W[i]
        ref.v_W[i] = 0.0
        ref.a_W[i] = 0.0
        ref.omega_W[i] = 0.0
        ref.alpha_W[i] = 0.0
        for j in range(3):
            ref.R_WB[i, j] = r.R_WB[i, j]
    r.n_samples += 1.0


@register("trajectory", "test-constant")
class ConstantPose:
    state_dtype = CONSTANT_DTYPE
    log_fields = (("samples", ("n_samples",)),)
    kernel = constant_sample

    @classmethod
    def data_size(cls, capacity_waypoints):
        return 1  # it keeps its pose in its record

    def __init__(self, capacity_waypoints, *, state=None, data=None):
        self.state = state_array(CONSTANT_DTYPE, state, "constant pose")

    def load(self, trajectory):
        last = trajectory.waypoints[-1]
        self.state["p_W"], self.state["R_WB"] = last.p_W, last.R_WB

    def reset(self):
        self.state["n_samples"] = 0.0


LSQ_DTYPE = np.dtype(
    [("status", F8), ("saturated", F8), ("n_nonfinite", F8), ("n_steps", F8), ("u_lo", F8), ("u_hi", F8)]
)


@numba.njit(cache=False)
def lsq_allocate(r, ar, f_ref_W, m_ref_B, R_WB, A):
    """u = A^T (A A^T)^-1 [R^T f; m], clipped to the input bounds: the minimum-norm inverse, no QP."""
    w = np.empty(6)
    for i in range(3):
        w[i] = R_WB[0, i] * f_ref_W[0] + R_WB[1, i] * f_ref_W[1] + R_WB[2, i] * f_ref_W[2]
        w[3 + i] = m_ref_B[i]
    if not np.all(np.isfinite(w)):
        r.n_nonfinite += 1.0
        return BEGIN_HELD
    u = A.T @ np.linalg.solve(A @ A.T, w)
    r.saturated = 0.0
    for i in range(u.shape[0]):
        ar.u_hz2[i] = min(max(u[i], r.u_lo), r.u_hi)
        if ar.u_hz2[i] != u[i]:
            r.saturated = 1.0
    r.n_steps += 1.0
    return ALLOC_DONE


@register("allocation", "test-least-squares")
class LeastSquaresAllocation:
    state_dtype = LSQ_DTYPE
    log_fields = (("lsq_steps", ("n_steps",)),)
    kernel = lsq_allocate  # no entries "qp", "finish": it answers ALLOC_DONE
    solves_compiled = True

    @staticmethod
    def arrays_dtype(n):
        return np.dtype([("u_hz2", F8, (n,))])

    def __init__(self, vehicle, params, *, state=None, arrays=None):
        self.state = state_array(LSQ_DTYPE, state, "least-squares allocation")
        self.state["u_lo"], self.state["u_hi"] = vehicle.u_min, vehicle.u_max

    def reset(self):
        for name in ("status", "saturated", "n_nonfinite", "n_steps"):
            self.state[name] = 0.0


V = load_vehicle("omnirotor")
F_PUSH_W = np.array([2.0, 0.0, 0.0])


def _hover(**kinds):
    """3 s of hover with a 2 N push at the EE tip from 0.5 s, the bypass estimator, the chosen blocks."""
    sim = Simulator(V, "free", SimParams(aero=AeroParams(model="nominal")).undisturbed(), seed=0)
    p, R = sim.default_start()
    p_E = p + R @ V.p_E_B_array
    params = ControllerParams(estimator=EstimatorParams(kind="bypass"), **kinds)
    ctl = InteractionController(V, params)

    def push(s, t):
        if abs(t - 0.5) < 0.5e-3:
            s.set_external_wrench(F_PUSH_W, at="ee")

    ctl_log, truth_log = run_closed_loop(sim, ctl, PoseTrajectory([Waypoint(0.0, p_E, R)]), 3.0, on_step=push)
    assert ctl.kernel_state is not None  # flown by the one compiled step, not from Python
    return ctl, ctl_log, truth_log.group("p_E_W") - p_E


def test_every_block_of_every_kind_has_its_typed_step():
    """Every controller kind has a typed step; each registered block (the package's and this file's) has a kernel
    with its kind's parameters, and whichever further entries it defines have theirs."""
    import inspect

    assert set(KIND_STEPS) == set(CONTROLLER_KINDS)
    for kind, signature in KIND_STEPS.items():
        entries = {"kernel": signature}
        for part in signature.split("Entry ")[1:] + signature.split("entries ")[1:]:
            for sub in part.split(", then "):
                entries[sub[: sub.index("(")]] = sub
        for name in block_names(kind):
            cls = block_class(kind, name)
            for entry, text in entries.items():
                fn = getattr(cls, entry, None)
                if fn is None:
                    assert entry != "kernel", (kind, name)
                    continue
                wanted = [a.strip() for a in text[text.index("(") + 1 : text.index(")")].split(",")]
                params = list(inspect.signature(getattr(fn, "py_func", fn)).parameters)
                assert len(params) == len(wanted), (kind, name, entry, params, wanted)
    assert {"ukf", "bypass"} <= set(block_names("estimator"))
    assert block_class("allocation", "box-qp").qp is not None and block_class("supervisor", "frame-checks").reference


def test_a_new_admittance_block_flies_the_hover():
    ctl, log, dp = _hover(admittance_kind="test-rigid")
    assert isinstance(ctl.admittance, RigidAdmittance) and np.shares_memory(ctl.admittance.state, ctl.state)
    assert ctl.admittance.state["n_steps"][0] == 3000  # its kernel ran every period, in the compiled step
    assert np.all(log.group("xi_p_W") == 0.0)
    np.testing.assert_array_equal(log.group("p_E_ref_W"), log.group("p_E_des_W"))  # it never yields ...
    f_seen = log.group("f_E_seen_W")  # ... although it was given the push (its own logged signal)
    np.testing.assert_allclose(f_seen[-1], F_PUSH_W, atol=0.1)
    # The default filter yields along the push towards f / K (2 cm); the rigid one holds the tip within a tenth
    # of that (the pose controller compensates the push).
    default, _, dp_default = _hover()
    yield_m = F_PUSH_W[0] / default.admittance.params.stiffness_pos[0]
    assert dp_default[-1, 0] > 0.8 * yield_m and abs(dp[-1, 0]) < 0.1 * yield_m, (dp[-1], dp_default[-1])


def test_a_new_pose_controller_flies_the_hover():
    ctl, log, _ = _hover(pose_kind="test-counting")
    assert isinstance(ctl.pose, CountingPose) and np.shares_memory(ctl.pose.state, ctl.state)
    np.testing.assert_array_equal(log.group("pose_steps"), np.arange(1.0, 3001.0))
    _, default_log, _ = _hover()
    for group in ("u_hz2", "omega_cmd_hz", "w_ref", "pose_err"):  # the same law, the same flight, bit for bit
        np.testing.assert_array_equal(log.group(group), default_log.group(group))


def test_new_supervisor_maps_and_trajectory_blocks_fly_the_hover():
    """The pass-through supervisor, the fixed nominal map and the constant pose, each reached by name in the one
    compiled step, fly the clean hover bit for bit as the default blocks do (which reject nothing there)."""
    kinds = dict(supervisor_kind="test-pass", maps_kind="test-fixed", trajectory_kind="test-constant")
    ctl, log, _ = _hover(**kinds)
    assert isinstance(ctl.supervisor, PassSupervisor) and np.shares_memory(ctl.supervisor.state, ctl.state)
    assert isinstance(ctl.scheduler, FixedMaps) and isinstance(ctl.trajectory_block, ConstantPose)
    steps = np.arange(1.0, 3001.0)
    for group in ("frames_seen", "map_calls", "samples"):  # each kernel ran once a period, logged by its block
        np.testing.assert_array_equal(log.group(group), steps)
    assert ctl.sizes.trajectory_capacity == 1  # the record is built from the blocks' own sizes
    default, default_log, _ = _hover()
    assert default.frame_causes == {name: 0 for name in default.frame_causes}  # nothing to reject: same input
    for group in ("u_hz2", "omega_cmd_hz", "w_ref", "pose_err", "p_E_des_W", "f_ext_W"):
        np.testing.assert_array_equal(log.group(group), default_log.group(group))


def test_a_least_squares_allocation_without_a_qp_flies_the_hover():
    ctl, log, dp = _hover(allocation_kind="test-least-squares")
    assert isinstance(ctl.allocator, LeastSquaresAllocation)
    np.testing.assert_array_equal(log.group("lsq_steps"), np.arange(1.0, 3001.0))
    # Its inputs are the minimum-norm inverse of the logged wrench reference (nothing saturated in hover) ...
    A = V.A_nom
    for k in (10, 1500, 2999):
        R = log.group("R_WB")[k].reshape(3, 3)
        w = log.group("w_ref")[k]
        u = np.linalg.pinv(A) @ np.r_[R.T @ w[:3], w[3:]]
        np.testing.assert_allclose(log.group("u_hz2")[k], u, rtol=1e-9, atol=1e-6 * np.abs(u).max())
    # ... and they hold the hover: the tip back near its start after the push (the admittance's yield, 2 cm).
    default, _, dp_default = _hover()
    assert np.linalg.norm(dp[-1] - dp_default[-1]) < 0.005, (dp[-1], dp_default[-1])
