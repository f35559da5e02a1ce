"""Rotor speed loop of the simulator (SPEC §1.4): first-order lag, saturation, dead band."""

import math

import numpy as np
import pytest

from omnirotor.errors import InputError
from omnirotor.messages import RotorCommand
from omnirotor.sim import SimParams, Simulator
from omnirotor.sim.params import RotorDynamicsParams
from omnirotor.sim.rotors import RotorBank
from omnirotor.vehicle import load_vehicle

V = load_vehicle("omnirotor")
DT = 1e-3


def test_step_response_reaches_63_percent_at_tau():
    tau = 0.025
    bank = RotorBank(V, RotorDynamicsParams(tau_m=tau), DT)
    bank.reset(np.zeros(8))
    cmd = np.full(8, 100.0)
    trace = []
    for _ in range(100):
        bank.step(cmd)
        trace.append(bank.omega_hz[0])
    k_tau = round(tau / DT)
    assert trace[k_tau - 1] == pytest.approx(100.0 * (1 - math.exp(-1)), rel=1e-9)  # 63.2 Hz at t = tau
    assert trace[k_tau - 2] < 63.0 < trace[k_tau - 1]
    assert trace[-1] == pytest.approx(100.0 * (1 - math.exp(-4)), rel=1e-9)
    np.testing.assert_allclose(bank.u_hz2, bank.omega_hz * np.abs(bank.omega_hz))


def test_saturation_clips_at_the_vehicle_limits():
    bank = RotorBank(V, RotorDynamicsParams(), DT)
    bank.reset(np.zeros(8))
    cmd = np.array([1e4, -1e4, 300.0, -300.0, np.inf, -np.inf, 219.0, -219.0])
    peak = np.zeros(8)
    for _ in range(1000):
        bank.step(cmd)
        peak = np.maximum(peak, np.abs(bank.omega_hz))
    np.testing.assert_allclose(bank.omega_hz, [220, -220, 220, -220, 220, -220, 219, -219], atol=1e-6)
    assert peak.max() <= 220.0
    # A unidirectional vehicle cannot reverse.
    hexa = load_vehicle("hexarotor-tilted")
    bank = RotorBank(hexa, RotorDynamicsParams(), DT)
    bank.reset(np.full(6, 150.0))
    for _ in range(1000):
        bank.step(np.full(6, -200.0))
    np.testing.assert_allclose(bank.omega_hz, 0.0, atol=1e-9)
    assert np.all(bank.omega_hz >= 0.0)


def test_dead_band_stops_slow_commands_only_when_enabled():
    cmd = np.array([20.0, -20.0, 29.9, 30.0, 40.0, -40.0, 0.0, 100.0])
    for enabled, expect in ((True, [0, 0, 0, 30, 40, -40, 0, 100]), (False, cmd)):
        bank = RotorBank(V, RotorDynamicsParams(dead_band=enabled), DT)
        bank.reset(np.full(8, 60.0))
        for _ in range(1500):
            bank.step(cmd)
        np.testing.assert_allclose(bank.omega_hz, expect, atol=1e-6)
    assert RotorDynamicsParams(dead_band=True).dead_band_hz == 30.0


def test_nan_command_holds_the_speed():
    bank = RotorBank(V, RotorDynamicsParams(), DT)
    bank.reset(np.full(8, 120.0))
    cmd = np.full(8, 150.0)
    cmd[2] = np.nan
    for _ in range(50):
        bank.step(cmd)
    assert bank.omega_hz[2] == 120.0
    assert np.all(np.isfinite(bank.omega_hz))


def test_simulator_rotors_follow_commands_through_the_lag():
    sim = Simulator(V, "free", SimParams(), seed=0)
    w0 = sim.truth.rotor_hz.copy()
    target = w0 + 20.0
    for _ in range(25):
        frame = sim.step(RotorCommand(sim.t, target))
    np.testing.assert_allclose(sim.truth.rotor_hz, w0 + 20.0 * (1 - math.exp(-1)), rtol=1e-9)
    # The measured speeds are the true ones plus a little noise.
    assert np.max(np.abs(frame.rotor_hz - sim.truth.rotor_hz)) < 5 * 0.5
    with pytest.raises(InputError):
        sim.step(RotorCommand(sim.t, np.zeros(6)))


def test_rotor_params_are_validated():
    for bad in ({"tau_m": 0.0}, {"tau_m": -1.0}, {"dead_band_hz": -5.0}):
        with pytest.raises(InputError):
            RotorDynamicsParams(**bad)
