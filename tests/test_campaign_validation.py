"""Campaign files are validated before anything runs (issue 26, item 3): rotor indices, tasks, sizes.

Each mistake is one :class:`~omnirotor.errors.InputError` (the CLI's one line and exit status 2).
"""

from __future__ import annotations

import pytest

from omnirotor.errors import InputError
from omnirotor.experiments.campaigns.spec import campaign_from_mapping
from omnirotor.limits import MAX_CAMPAIGN_RUNS


def _file(**vary) -> dict:
    return {"task": "hover", "runs": 2, "vary": vary}


def test_a_failed_rotor_the_vehicle_does_not_have_is_refused():
    with pytest.raises(InputError, match=r"rotor 99 does not exist.*rotors 1\.\.8 \(0 = none\)"):
        campaign_from_mapping(_file(failed_rotor={"dist": "constant", "value": 99}))
    with pytest.raises(InputError, match="rotor 9 does not exist"):
        campaign_from_mapping(_file(failed_rotor={"dist": "choice", "values": [0, 3, 9]}))
    with pytest.raises(InputError, match="outside"):
        campaign_from_mapping(_file(failed_rotor={"dist": "constant", "value": -1}))
    spec = campaign_from_mapping(_file(failed_rotor={"dist": "choice", "values": [0, 1, 8]}))  # the edges are fine
    assert dict(spec.vary)["failed_rotor"].support() == (0, 1, 8)


def test_unknown_tasks_parameters_and_sizes_are_refused():
    with pytest.raises(InputError, match="task"):
        campaign_from_mapping({"task": "juggling", "runs": 2})
    with pytest.raises(InputError, match="unknown parameter"):
        campaign_from_mapping(_file(rotor_count={"dist": "constant", "value": 3}))
    with pytest.raises(InputError, match=rf"runs must lie in 1\.\.{MAX_CAMPAIGN_RUNS}"):
        campaign_from_mapping({"task": "hover", "runs": MAX_CAMPAIGN_RUNS + 1})
    with pytest.raises(InputError, match="runs must lie"):
        campaign_from_mapping({"task": "hover", "runs": 0})


def test_every_parameter_carries_its_target_and_a_typed_apply():
    from omnirotor.experiments.campaigns.spec import PARAMETERS

    for p in PARAMETERS.values():
        assert p.target in ("plant", "controller", "scenario", "fault"), p.name
        assert (p.apply is None) == (p.target == "fault"), p.name


def test_a_runs_drawn_values_reach_the_plant_controller_and_scenario_typed_not_as_text():
    from omnirotor.experiments.campaigns.spec import run_options

    vary = {
        "gamma": {"dist": "constant", "value": 5.5},
        "rotor_gain_error_std": {"dist": "constant", "value": 0.05},
        "friction": {"dist": "constant", "value": 0.3},
        "sensor_noise_scale": {"dist": "constant", "value": 2.0},
        "mass_error": {"dist": "constant", "value": 0.1},
        "slide_roll_deg": {"dist": "constant", "value": 40.0},
        "controller.observer.cutoff_hz": {"dist": "constant", "value": 7.0},
        "sim.sensors.mocap_rate_hz": {"dist": "constant", "value": 120},
    }
    job = run_options(campaign_from_mapping({"task": "sliding", "runs": 1, "vary": vary}), 0)
    o = job.options
    assert o.plant.sim_overrides == () and o.overrides == ()  # nothing written as text
    sp = o.plant_sim_params()
    assert sp.aero.gamma == 5.5 and sp.aero.model == "spec7" and sp.aero.gain_error_std == 0.05
    assert sp.aero.error_seed == job.derived["rotor_error_seed"] and sp.scene.friction == 0.3
    base = o.sim_params().sensors
    assert sp.sensors.gyro_noise_std == 2.0 * base.gyro_noise_std
    assert sp.sensors.mocap_rate_hz == 120.0 and isinstance(sp.sensors.mocap_rate_hz, float)  # the field's type
    assert o.plant.mass_scale == 1.1 and o.scenario.slide_roll_deg == 40.0
    assert o.controller_params().observer.cutoff_hz == 7.0


def test_typed_values_and_text_overrides_give_the_same_parameters():
    from omnirotor.config import apply_overrides, apply_values
    from omnirotor.sim.params import SimParams

    text = apply_overrides(SimParams(), ["aero.gamma=4.5", 'aero.model="spec7"', "scene.friction=0.25"])
    typed = apply_values(SimParams(), [("aero.gamma", 4.5), ("aero.model", "spec7"), ("scene.friction", 0.25)])
    assert text == typed
    with pytest.raises(InputError, match="unknown key 'gama'"):
        apply_values(SimParams(), [("aero.gama", 1.0)])
