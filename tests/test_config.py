import dataclasses

import pytest

from omnirotor.config import apply_overrides, from_mapping
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
