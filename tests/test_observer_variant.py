"""Proof of the block contract (issue 11): a new observer, defined in this file alone and registered with one
line, flies the hover through the public API, inside the controller's compiled step.

Its ``log_fields`` add a signal of its own to the controller's log (issue 23 item 2: the log record is derived
from the blocks' declarations).

The variant estimates the force only (the first-order filter of SPEC §4.3 eq. 7, no low-pass, no moment): with
a push at the EE tip, the logged moment estimate stays exactly zero while the force is recovered, which the
default momentum observer (it estimates the moment the push makes about the CoM) would not give.
"""

import math

import numba
import numpy as np

from omnirotor.blocks import block_class, register
from omnirotor.control.controller import ControllerParams, InteractionController
from omnirotor.control.estimator import EstimatorParams
from omnirotor.control.trajectory import PoseTrajectory, Waypoint
from omnirotor.experiments.loop import run_closed_loop
from omnirotor.sim import SimParams, Simulator
from omnirotor.sim.params import AeroParams
from omnirotor.vehicle import load_vehicle

F8 = np.float64
FORCE_ONLY_DTYPE = np.dtype(
    [
        ("f_ext_W", F8, 3),  # the contract's outputs: the interaction estimate ...
        ("m_ext_B", F8, 3),
        ("f_filt_W", F8, 3),  # ... and what the pose controller compensates
        ("m_filt_B", F8, 3),
        ("n_nonfinite", F8),
        ("n_steps", F8),
        ("gain_force", F8, 3),
        ("mass_kg", F8),
        ("gravity", F8),
    ]
)


@numba.njit(cache=False)
def force_only_step(r, A, u, a_W, R, omega_B, dt):
    """f_hat += L dt (m (a + g e3) - R A1 u - f_hat); the moment estimate is zero."""
    f = np.zeros(3)
    for i in range(3):
        acc = 0.0
        for j in range(u.shape[0]):
            acc += A[i, j] * u[j]
        f[i] = acc
    if not (np.all(np.isfinite(f)) and np.all(np.isfinite(a_W)) and np.all(np.isfinite(R))):
        r.n_nonfinite += 1.0
        return
    g = np.array([0.0, 0.0, r.gravity])
    residual = r.mass_kg * (a_W + g) - R @ f
    for i in range(3):
        r.f_ext_W[i] += r.gain_force[i] * dt * (residual[i] - r.f_ext_W[i])
        r.f_filt_W[i] = r.f_ext_W[i]
    r.n_steps += 1.0


@register("observer", "test-force-only")
class ForceOnlyObserver:
    state_dtype = FORCE_ONLY_DTYPE
    log_fields = ("f_ext_W", "m_ext_B", ("force_steps", ("n_steps",)))  # the last: a signal of its own, renamed
    kernel = force_only_step

    def __init__(self, vehicle, params, *, state=None):
        self.state = np.zeros(1, FORCE_ONLY_DTYPE) if state is None else state
        self.state["gain_force"] = params.gain_force
        self.state["mass_kg"] = vehicle.mass
        self.state["gravity"] = vehicle.gravity
        self.f_ext_W = self.state[0]["f_ext_W"]

    def reset(self):
        for name in ("f_ext_W", "m_ext_B", "f_filt_W", "m_filt_B"):
            self.state[name] = 0.0
        self.state["n_steps"] = 0.0


def test_a_new_observer_flies_the_hover_through_the_public_api():
    vehicle = load_vehicle("omnirotor")
    assert block_class("observer", "test-force-only") is ForceOnlyObserver
    sim = Simulator(vehicle, "free", SimParams(aero=AeroParams(model="nominal")).undisturbed(), seed=0)
    p, R = sim.default_start()
    p_E = p + R @ vehicle.p_E_B_array
    params = ControllerParams(estimator=EstimatorParams(kind="bypass"), observer_kind="test-force-only")
    ctl = InteractionController(vehicle, params)
    assert isinstance(ctl.observer, ForceOnlyObserver)
    f_W = np.array([2.0, 0.0, 0.0])

    def push(s, t):
        if abs(t - 0.5) < 0.5e-3:  # once, at 0.5 s
            s.set_external_wrench(f_W, at="ee")

    ctl_log, truth_log = run_closed_loop(sim, ctl, PoseTrajectory([Waypoint(0.0, p_E, R)]), 3.0, on_step=push)
    # The compiled step ran the variant's kernel every period (its own counter, in the controller's state).
    assert ctl.kernel_state is not None and ctl.observer.state["n_steps"][0] == 3000
    assert np.shares_memory(ctl.observer.state, ctl.state)
    # Its log declaration is the log: its own signal is a group of the controller's log, row by row.
    np.testing.assert_array_equal(ctl_log.group("force_steps"), np.arange(1.0, 3001.0))
    assert ctl_log.column_names.index("force_steps") == ctl_log.column_names.index("m_ext_B.z") + 1
    f_hat, m_hat = ctl_log.group("f_ext_W"), ctl_log.group("m_ext_B")
    np.testing.assert_allclose(f_hat[-1], f_W, atol=0.05)  # the force is recovered ...
    assert np.all(m_hat == 0.0)  # ... and the moment is not estimated at all: it is the variant that flew
    # It hovers upright: the admittance yields by f / K along x and the tip holds within a few centimetres;
    # the moment of the push about the CoM, not compensated, turns the vehicle in yaw (the default observer
    # would compensate it: tests/test_closed_loop.py).
    dp = truth_log.group("p_E_W")[-500:] - p_E
    assert np.abs(dp[:, 1:]).max() < 0.03 and 0.0 < dp[-1, 0] < 0.2, dp[-1]
    R_end = truth_log.group("R_WB")[-1].reshape(3, 3)
    assert R_end[2, 2] > math.cos(math.radians(1.0))


def test_the_observer_is_chosen_by_name_from_the_parameters():
    from omnirotor.control.controller import load_controller_params
    from omnirotor.errors import InputError

    params = load_controller_params(overrides=["observer_kind=test-force-only"])
    assert params.observer_kind == "test-force-only"
    assert ControllerParams().observer_kind == "momentum"
    try:
        ControllerParams(observer_kind="no-such-observer")
    except InputError as exc:
        assert "momentum" in str(exc) and "test-force-only" in str(exc)  # the message lists the registered ones
    else:
        raise AssertionError("an unknown observer name was accepted")
