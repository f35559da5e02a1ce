from importlib.resources import files

from omnirotor.control.controller import ControllerParams, load_controller_params


def test_shipped_paper_preset_equals_the_defaults():
    path = files("omnirotor") / "presets" / "controller" / "paper.toml"
    assert load_controller_params(str(path)) == ControllerParams()
