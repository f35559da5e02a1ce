"""Proof of the block contract for the kinds the composer reaches through the registry (issue 23 item 3): a new
admittance block and a new pose controller, each defined in this file alone and registered with one line, fly
the hover through the public API inside the controller's one compiled step (the observer's variant is in
tests/test_observer_variant.py).

* "test-rigid" admittance never yields: the compliant reference is the desired one, its offset stays zero;
* "test-counting" pose controller is the geometric PID of SPEC §4.1 (the package's ``pose_step``) plus a step
  counter that it logs: the flight is bit for bit the default one, and the counter says its kernel ran.
"""

import numba
import numpy as np

from omnirotor.blocks import KIND_STEPS, block_class, block_names, register, state_array
from omnirotor.control.controller import ControllerParams, InteractionController
from omnirotor.control.estimator import EstimatorParams
from omnirotor.control.pose import STATE_DTYPE as POSE_DTYPE
from omnirotor.control.pose import PoseController, pose_step
from omnirotor.control.trajectory import PoseTrajectory, Waypoint
from omnirotor.experiments.loop import run_closed_loop
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


def test_every_block_of_a_kind_reached_through_the_registry_has_its_typed_step():
    """Each registered block (the package's and this file's) has a kernel with its kind's parameters, in order."""
    import inspect

    assert set(KIND_STEPS) == {"observer", "admittance", "pose", "estimator"}
    for kind, signature in KIND_STEPS.items():
        wanted = [a.strip() for a in signature[signature.index("(") + 1 : signature.index(")")].split(",")]
        for name in block_names(kind):
            kernel = block_class(kind, name).kernel
            params = list(inspect.signature(getattr(kernel, "py_func", kernel)).parameters)
            assert len(params) == len(wanted), (kind, name, params, wanted)
    assert {"ukf", "bypass"} <= set(block_names("estimator"))


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
