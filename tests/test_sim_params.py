"""Simulator parameters: TOML loading and validation."""

import pytest

from omnirotor.errors import InputError
from omnirotor.sim import SimParams, load_sim_params
from omnirotor.sim.params import SceneParams, SensorParams


def test_load_sim_params_from_toml(tmp_path):
    f = tmp_path / "sim.toml"
    f.write_text(
        "dt = 0.001\nsubsteps = 2\nprovide_state = false\n"
        "[rotors]\ntau_m = 0.03\ndead_band = true\n"
        '[aero]\nmodel = "nominal"\nkappa0 = 1.2\n'
        "[sensors]\nmocap_rate_hz = 120\nimu_offset_B = [0.0, 0.0, 0.041]\n"
        "[scene]\nwall_point = [0.5, -0.8, 1.4]\npipe_radius = 0.5\n"
    )
    p = load_sim_params(f)
    assert p.substeps == 2 and p.provide_state is False
    assert p.rotors.tau_m == 0.03 and p.rotors.dead_band
    assert p.aero.model == "nominal" and p.aero.kappa0 == 1.2
    assert p.sensors.mocap_rate_hz == 120.0 and p.sensors.imu_offset_B == (0.0, 0.0, 0.041)
    assert p.scene.wall_point == (0.5, -0.8, 1.4) and p.scene.pipe_radius == 0.5
    assert p.scene.hole_entrance == SceneParams().hole_entrance  # untouched defaults kept


@pytest.mark.parametrize(
    "text",
    [
        "dtt = 0.001\n",
        "[aero]\nkapa0 = 1.2\n",
        "[scene]\npipe_radius = -1.0\n",
        '[aero]\nmodel = "cfd"\n',
        "[sensors]\nmocap_rate_hz = 0\n",
        "dt = 0.001\nsubsteps = 0\n",
        "dt = 0.008\nsubsteps = 2\n",  # contact time constant 5 ms < 2 physics steps (dt / substeps = 4 ms)
        "[scene]\nfunnel_entrance_diameter = 0.01\n",
        "[scene]\nwall_point = [1.0, 2.0]\n",
        "not toml = = \n",
    ],
)
def test_bad_sim_params_raise_input_error(tmp_path, text):
    f = tmp_path / "bad.toml"
    f.write_text(text)
    with pytest.raises(InputError):
        load_sim_params(f)


def test_defaults_are_the_spec_values():
    p = SimParams()
    assert p.dt == 1e-3 and p.rotors.tau_m == 0.025 and p.rotors.dead_band_hz == 30.0
    assert (p.aero.kappa0, p.aero.gamma, p.aero.rho, p.aero.advance_ratio_ref, p.aero.jet_spread) == (
        1.18,
        4.0,
        1.225,
        0.6,
        0.10,
    )
    assert p.scene.wall_point == (0.637, -0.827, 1.429)
    assert p.scene.tilted_wall_point == (0.639, -0.848, 1.365) and p.scene.tilted_wall_angle_deg == 30.0
    assert p.scene.pipe_centre == (0.0261, 1.4952, 0.7648) and p.scene.pipe_radius == 0.55
    assert p.scene.funnel_length == 0.10 and p.scene.hole_diameter == 0.019
    assert p.scene.funnel_entrance_diameter == 0.080
    assert SensorParams().mocap_rate_hz == 100.0
    with pytest.raises(InputError):
        SensorParams(acc_noise_std=-0.1)
