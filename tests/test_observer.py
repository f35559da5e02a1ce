"""Wrench observer (SPEC §4.3) on synthetic data that obey the rigid-body equations exactly."""

import dataclasses
import math

import numpy as np
import pytest

from omnirotor.control.observer import ObserverParams, WrenchObserver, lowpass_coefficient
from omnirotor.errors import InputError
from omnirotor.messages import StateEstimate
from omnirotor.so3 import R_from_rpy, exp_so3
from omnirotor.vehicle import load_vehicle

DT = 1e-3


@pytest.fixture(scope="module")
def vehicle():
    return load_vehicle("omnirotor")


class Plant:
    """Synthetic vehicle: m a = R (gain A1 u) - m g e3 + f_ext; J dw = -w x Jw + A2 u + m_ext (Euler)."""

    def __init__(self, vehicle, R0, omega0=(0.0, 0.0, 0.0), thrust_gain=1.0, seed=0):
        self.v = vehicle
        self.A = vehicle.A_nom
        self.J = vehicle.inertia
        self.Jinv = np.linalg.inv(self.J)
        self.R = np.array(R0, float)
        self.w = np.array(omega0, float)
        self.gain = thrust_gain
        self.rng = np.random.default_rng(seed)
        self.f_ext = np.zeros(3)
        self.m_ext = np.zeros(3)

    def state(self, u, t):
        a = (self.R @ (self.gain * self.A[:3] @ u) + self.f_ext) / self.v.mass - [0, 0, self.v.gravity]
        return StateEstimate(t=t, p_W=np.zeros(3), v_W=np.zeros(3), a_W=a, R_WB=self.R.copy(), omega_B=self.w.copy())

    def advance(self, u):
        wdot = self.Jinv @ (-np.cross(self.w, self.J @ self.w) + self.A[3:] @ u + self.m_ext)
        self.R = self.R @ exp_so3(self.w * DT)
        self.w = self.w + wdot * DT


def _run(obs, plant, seconds, u_fn, t0=0.0):
    """Step plant and observer; returns the (k, 6) filtered outputs and (k, 6) raw estimates."""
    n = int(round(seconds / DT))
    outs, raws = np.empty((n, 6)), np.empty((n, 6))
    for k in range(n):
        u = u_fn(k)
        if k > 0 or t0 > 0:
            plant.advance(u)
        obs.step(plant.state(u, t0 + k * DT), u, plant.A, DT)
        outs[k] = obs.output
        raws[k] = obs.raw
    return outs, raws


def test_lowpass_coefficient_of_the_paper():
    assert lowpass_coefficient(10.0, 1e-3) == pytest.approx(0.0591, abs=5e-5)
    assert lowpass_coefficient(math.inf, 1e-3) == 1.0


def test_zero_estimate_without_external_wrench(vehicle):
    # Rotating, time-varying inputs, anisotropic inertia (gyroscopic terms active): no external wrench.
    veh = dataclasses.replace(vehicle, inertia_diag=(0.010, 0.012, 0.015))
    plant = Plant(veh, R_from_rpy(0.5, -0.4, 1.0), omega0=(1.0, -2.0, 0.5))
    rng = np.random.default_rng(8)
    u_hover = veh.hover_input()
    obs = WrenchObserver(veh)
    outs, _ = _run(obs, plant, 2.0, lambda k: u_hover + 3000.0 * rng.normal(size=8))
    assert np.abs(outs[:, :3]).max() < 1e-9
    assert np.abs(outs[:, 3:]).max() < 2e-3  # O(dt) from the Euler data of the gyroscopic term


def test_constant_wrench_is_recovered_with_the_paper_time_constants(vehicle):
    plant = Plant(vehicle, R_from_rpy(0.3, 0.2, -0.5))
    f_true, m_true = np.array([2.0, -1.0, 0.5]), np.array([0.1, -0.2, 0.05])
    plant.f_ext[:] = f_true
    plant.m_ext[:] = m_true
    u = vehicle.hover_input(plant.R)
    obs = WrenchObserver(vehicle)
    outs, raws = _run(obs, plant, 1.5, lambda k: u)
    t = np.arange(outs.shape[0]) * DT
    # Raw estimates: first-order lags of time constant 1/L = 66.7 ms (force) and 1/K_I = 40 ms (moment).
    for tau, cols, true in ((1 / 15.0, slice(0, 3), f_true), (1 / 25.0, slice(3, 6), m_true)):
        k = int(round(tau / DT))
        np.testing.assert_allclose(raws[k, cols], true * (1 - math.exp(-1)), rtol=0.02)
        # Filtered output: the cascade with the 10 Hz low-pass (time constant 1 / (2 pi 10)).
        tf = 1 / (2 * math.pi * 10.0)
        cascade = 1 - (tau * np.exp(-t / tau) - tf * np.exp(-t / tf)) / (tau - tf)
        np.testing.assert_allclose(outs[:, cols], np.outer(cascade, true), atol=0.015 * np.abs(true).max())
    np.testing.assert_allclose(outs[-1], np.concatenate([f_true, m_true]), rtol=1e-6, atol=1e-8)


def test_uses_the_given_map_and_bias(vehicle):
    # A vehicle whose real thrust is 15 % above the map shows a force "bias" = 0.15 R A1 u; handing the
    # observer the true map removes it, and a configured bias is subtracted from the output.
    plant = Plant(vehicle, R_from_rpy(0.0, 0.0, 0.3), thrust_gain=1.15)
    u = vehicle.hover_input()
    obs = WrenchObserver(vehicle)
    outs, _ = _run(obs, plant, 2.0, lambda k: u)
    assert outs[-1, 2] == pytest.approx(0.15 * vehicle.weight, rel=1e-4)
    plant2 = Plant(vehicle, np.eye(3), thrust_gain=1.15)
    plant2.A = 1.15 * vehicle.A_nom
    plant2.gain = 1.0
    obs2 = WrenchObserver(vehicle, ObserverParams(bias=(0.0, 0.0, 1.3, 0.0, 0.0, 0.0)))
    outs2, _ = _run(obs2, plant2, 2.0, lambda k: u)
    np.testing.assert_allclose(outs2[-1], [0, 0, -1.3, 0, 0, 0], atol=1e-6)


def test_zeroing_removes_a_constant_bias_and_keeps_real_forces(vehicle):
    plant = Plant(vehicle, np.eye(3), thrust_gain=1.15)
    u = vehicle.hover_input()
    params = ObserverParams(zero_at_start=True, zero_settle_s=1.0, zero_window_s=0.5)
    obs = WrenchObserver(vehicle, params)
    outs, _ = _run(obs, plant, 1.6, lambda k: u)
    k_capture = int(round(1.5 / DT))
    assert np.all(outs[: k_capture - 1] == 0.0)  # silent while settling and capturing
    assert obs.zeroed
    assert obs.offset[2] == pytest.approx(0.15 * vehicle.weight, rel=1e-3)
    assert np.abs(outs[k_capture + 1 :]).max() < 1e-3  # no jump at the capture
    # The full (unzeroed) estimate, which the pose controller compensates, still holds the model error.
    assert obs.filtered[2] == pytest.approx(0.15 * vehicle.weight, rel=1e-3)
    # A real external force after the zeroing is estimated at its full value.
    plant.f_ext[:] = [0.0, 2.0, 0.0]
    outs, _ = _run(obs, plant, 1.5, lambda k: u, t0=1.6)
    np.testing.assert_allclose(outs[-1, :3], [0.0, 2.0, 0.0], atol=1e-3)
    obs.reset()
    assert not obs.zeroed and np.all(obs.offset == 0.0)


def test_outputs_are_preallocated_views(vehicle):
    obs = WrenchObserver(vehicle)
    plant = Plant(vehicle, np.eye(3))
    u = vehicle.hover_input()
    f1, m1 = obs.step(plant.state(u, 0.0), u, plant.A, DT)
    f2, m2 = obs.step(plant.state(u, DT), u, plant.A, DT)
    assert f1 is f2 and m1 is m2
    assert np.shares_memory(f1, obs.state) and np.shares_memory(m1, obs.state)


def test_validation():
    with pytest.raises(InputError):
        ObserverParams(gain_force=(0.0, 1.0, 1.0))
    with pytest.raises(InputError):
        ObserverParams(cutoff_hz=0.0)
    with pytest.raises(InputError):
        ObserverParams(bias=(0.0,) * 5)
    with pytest.raises(InputError):
        ObserverParams(zero_window_s=0.0)
    ObserverParams(cutoff_hz=math.inf)
