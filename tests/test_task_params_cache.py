"""A task's simulator and controller parameters, built once per combination (issue 16): equal to building them anew."""

import dataclasses

import pytest

from omnirotor.config import apply_overrides
from omnirotor.control.admittance import AdmittanceParams
from omnirotor.control.controller import load_controller_params
from omnirotor.errors import InputError
from omnirotor.experiments.loop import _controller_params
from omnirotor.experiments.tasks.common import ExperimentOptions
from omnirotor.sim.params import AeroParams, SimParams


def _sim_params_anew(o: ExperimentOptions) -> SimParams:
    params = SimParams(aero=AeroParams(model=o.truth))
    params = params if o.disturbances else params.undisturbed()
    return apply_overrides(params, list(o.sim_overrides))


def _controller_params_anew(o: ExperimentOptions, admittance):
    """Built without the cache: the file's (or the default) parameters, then the task's choices."""
    base = load_controller_params(o.controller_config)
    adm = admittance if o.controller_config is None else None
    return _controller_params(base, adm, o.solver, o.estimator, tuple(o.overrides))


@pytest.mark.parametrize(
    "kw",
    [
        {},
        {"truth": "spec7", "disturbances": False},
        {"sim_overrides": ("aero.gamma=9", "sensors.mocap_latency_s=0.01")},
        {"sim_overrides": ("aero.gamma=3",), "estimator": "bypass", "solver": "daqp"},
        {"overrides": ("observer.cutoff_hz=4",)},
    ],
)
def test_params_equal_those_built_anew(kw, tmp_path):
    o = ExperimentOptions(**kw)
    assert o.sim_params() == _sim_params_anew(o)
    assert o.sim_params() is o.sim_params()  # built once
    for adm in (None, AdmittanceParams.preset("free"), AdmittanceParams.preset("SD")):
        assert o.controller_params(adm) == _controller_params_anew(o, adm)
    cfg = tmp_path / "ctl.toml"
    cfg.write_text("[observer]\ncutoff_hz = 3.0\n")
    f = dataclasses.replace(o, controller_config=str(cfg))
    got = f.controller_params(AdmittanceParams.preset("SD"))
    assert got == _controller_params_anew(f, AdmittanceParams.preset("SD"))
    cfg.write_text("[observer]\ncutoff_hz = 6.0\n[pose]\nk_p = [1.0, 2.0, 3.0]\n")  # a file is read again
    again = f.controller_params(None)
    assert again == _controller_params_anew(f, None)
    assert again.pose.k_p == (1.0, 2.0, 3.0)


def test_different_options_give_different_params_and_bad_ones_still_fail():
    a = ExperimentOptions(sim_overrides=("aero.gamma=5",)).sim_params()
    b = ExperimentOptions(sim_overrides=("aero.gamma=6",)).sim_params()
    assert (a.aero.gamma, b.aero.gamma) == (5.0, 6.0)
    assert ExperimentOptions(estimator="bypass").controller_params().estimator.kind == "bypass"
    assert ExperimentOptions().controller_params().estimator.kind == "ukf"
    for _ in range(2):  # an error is not cached as a result
        with pytest.raises(InputError):
            ExperimentOptions(sim_overrides=("aero.nope=1",))
        with pytest.raises(InputError):
            ExperimentOptions(overrides=("observer.nope=1",)).controller_params()
