import dataclasses

import pytest

from omnirotor.config import apply_overrides, apply_values, from_mapping
from omnirotor.errors import InputError


@dataclasses.dataclass(frozen=True)
class Inner:
    gain: float = 1.0
    axes: tuple[float, float, float] = (1.0, 2.0, 3.0)


@dataclasses.dataclass(frozen=True)
class Outer:
    name: str = "x"
    on: bool = True
    inner: Inner = Inner()

    def __post_init__(self):
        if self.inner.gain < 0:
            raise InputError("gain must be >= 0")


def test_from_mapping_nested_and_types():
    o = from_mapping(Outer, {"name": "y", "inner": {"gain": 2, "axes": [0, 0, 1]}})
    assert o.inner.gain == 2.0 and isinstance(o.inner.gain, float) and o.inner.axes == (0.0, 0.0, 1.0)


@pytest.mark.parametrize(
    "data,match",
    [
        ({"nme": "typo"}, "unknown key"),
        ({"inner": {"gian": 1}}, "unknown key"),
        ({"on": 1}, "true or false"),
        ({"inner": {"gain": "fast"}}, "number"),
        ({"inner": {"axes": [1, 2]}}, "3 values"),
        ({"inner": {"gain": -1.0}}, "gain"),
    ],
)
def test_from_mapping_rejects(data, match):
    with pytest.raises(InputError, match=match):
        from_mapping(Outer, data)


def test_dotted_overrides():
    o = apply_overrides(Outer(), ["inner.gain=3.5", "name=abc", "inner.axes=[1, 1, 1]"])
    assert o.inner.gain == 3.5 and o.name == "abc" and o.inner.axes == (1.0, 1.0, 1.0)
    with pytest.raises(InputError, match="unknown key"):
        apply_overrides(Outer(), ["inner.gainz=1"])
    with pytest.raises(InputError, match="key=value"):
        apply_overrides(Outer(), ["inner.gain"])
    with pytest.raises(InputError, match="gain"):
        apply_overrides(Outer(), ["inner.gain=-2"])


def one_by_one(obj, overrides):
    """The overrides applied one at a time (each a replace of its own), as the function did before batching."""
    for item in overrides:
        obj = apply_overrides(obj, [item])
    return obj


def test_overrides_batched_equal_one_at_a_time_later_keys_winning():
    items = ["inner.gain=3.5", "name=abc", "inner.gain=2", "inner={gain = 7.0}", "inner.axes=[1, 1, 1]", "on=false"]
    assert apply_overrides(Outer(), items) == one_by_one(Outer(), items) == Outer("abc", False, Inner(7.0, (1, 1, 1)))
    # the keys are checked in order: the first bad one is the error, as before
    with pytest.raises(InputError, match="gainz"):
        apply_overrides(Outer(), ["name=a", "inner.gainz=1", "nme=2"])
    with pytest.raises(InputError, match="'x' is not a parameter group"):
        apply_overrides(Outer(), ["name.x=1", "inner.gain=-1"])


def test_campaign_plant_overrides_batched_equal_one_at_a_time():
    from omnirotor.experiments.campaigns.runner import load_campaign, run_options
    from omnirotor.sim.params import SimParams

    spec = load_campaign(None, "hover", quick=True)
    for i in range(12):
        values = list(run_options(spec, i).options.plant.sim_values)  # a campaign's drawn values, typed
        assert len(values) > 15
        one_at_a_time = SimParams()
        for item in values:
            one_at_a_time = apply_values(one_at_a_time, [item])
        assert apply_values(SimParams(), values) == one_at_a_time


@pytest.mark.parametrize(
    "text", ["0", "-3", "+12", "7.3698364447390325", "-0.0", "1e5", "1E+05", "2.5e-3", "0.000912992758492902"]
)
def test_number_overrides_parse_as_toml_does(text):
    import tomllib

    from omnirotor.config import _parse_scalar

    want = tomllib.loads(f"v = {text}")["v"]
    got = _parse_scalar(text)
    assert type(got) is type(want) and got == want and str(got) == str(want)
