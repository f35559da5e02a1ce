"""Regions of the sphere of attitudes, and which one a hover attitude or force direction falls in (SPEC §3.3).

The piecewise-linear wrench map keeps one map per region of the sphere of *up directions*
``v_B = R_WBᵀ e3`` (the world up axis seen in the body frame; upright hover gives ``v_B = e3``). In hover
the body-frame thrust force is ``R_WBᵀ m g e3``, so the direction of a measured hover force gives the same
``v_B``. A partition is data (TOML, see ``presets/regions/paper.toml``): each region is a union of closed
azimuth intervals times one closed elevation interval, and the first region that contains a direction
wins. Angles are degrees in files and radians in code.
"""

from __future__ import annotations

import dataclasses
import math
from importlib import resources
from pathlib import Path

import numpy as np

from omnirotor.config import from_mapping, load_toml
from omnirotor.errors import InputError

__all__ = ["Region", "Partition", "load_partition", "azimuth_elevation"]


@dataclasses.dataclass(frozen=True)
class Region:
    """One region: closed azimuth intervals x a closed elevation interval [deg].

    Attributes:
        name: e.g. "R1".
        azimuth_deg: list of [lo, hi] azimuth intervals within [-180, 180].
        elevation_deg: [lo, hi] within [-90, 90].
        sample_azimuth_deg: narrower intervals to draw identification attitudes from (default: the region).
        sample_elevation_deg: narrower elevation interval for sampling (default: the region).
    """

    name: str
    azimuth_deg: tuple[tuple[float, float], ...]
    elevation_deg: tuple[float, float]
    sample_azimuth_deg: tuple[tuple[float, float], ...] = ()
    sample_elevation_deg: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        for lo, hi in self.azimuth_deg + self.sample_azimuth_deg:
            if not (-180.0 <= lo <= hi <= 180.0):
                raise InputError(f"region {self.name}: azimuth interval [{lo}, {hi}] not within [-180, 180]")
        for pair in (self.elevation_deg, self.sample_elevation_deg or self.elevation_deg):
            if len(pair) != 2 or not (-90.0 <= pair[0] <= pair[1] <= 90.0):
                raise InputError(f"region {self.name}: elevation interval {pair} not within [-90, 90]")
        az = tuple((math.radians(lo), math.radians(hi)) for lo, hi in self.azimuth_deg)
        object.__setattr__(self, "_az_rad", az)
        object.__setattr__(self, "_el_rad", (math.radians(self.elevation_deg[0]), math.radians(self.elevation_deg[1])))

    def contains(self, az: float, el: float) -> bool:
        """True if (azimuth, elevation) [rad] lies in the region (closed intervals)."""
        lo, hi = self._el_rad  # type: ignore[attr-defined]
        if el < lo or el > hi:
            return False
        return any(a <= az <= b for a, b in self._az_rad)  # type: ignore[attr-defined]

    def sample_up_direction(self, rng: np.random.Generator) -> np.ndarray:
        """A random up direction ``v_B`` drawn uniformly on the sphere within the sampling box."""
        az_iv = self.sample_azimuth_deg or self.azimuth_deg
        el_iv = self.sample_elevation_deg or self.elevation_deg
        widths = np.array([hi - lo for lo, hi in az_iv])
        k = int(rng.choice(len(az_iv), p=widths / widths.sum())) if widths.sum() > 0 else 0
        az = math.radians(rng.uniform(*az_iv[k]))
        # Uniform on the sphere: sin(el) uniform.
        s = rng.uniform(math.sin(math.radians(el_iv[0])), math.sin(math.radians(el_iv[1])))
        el = math.asin(s)
        return np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])


def azimuth_elevation(v_B: np.ndarray) -> tuple[float, float]:
    """Azimuth and elevation [rad] of a body-frame direction (need not be unit)."""
    x, y, z = float(v_B[0]), float(v_B[1]), float(v_B[2])
    return math.atan2(y, x), math.atan2(z, math.hypot(x, y))


@dataclasses.dataclass(frozen=True)
class Partition:
    """An ordered list of regions covering the sphere of up directions."""

    name: str
    regions: tuple[Region, ...]

    def __post_init__(self) -> None:
        names = [r.name for r in self.regions]
        if not names:
            raise InputError(f"partition {self.name!r}: no regions")
        if len(set(names)) != len(names):
            raise InputError(f"partition {self.name!r}: duplicate region names")
        # Every direction must fall in some region: check on a dense grid.
        from omnirotor.vehicle import fibonacci_sphere

        for v in fibonacci_sphere(2000):
            if self.index_of_direction(v) < 0:
                az, el = azimuth_elevation(v)
                raise InputError(
                    f"partition {self.name!r} leaves a hole at azimuth {math.degrees(az):.1f} deg, "
                    f"elevation {math.degrees(el):.1f} deg"
                )

    @property
    def names(self) -> list[str]:
        """Region names in order."""
        return [r.name for r in self.regions]

    def index_of_direction(self, v_B: np.ndarray) -> int:
        """Index of the first region containing the up direction ``v_B`` (body frame), or -1."""
        az, el = azimuth_elevation(v_B)
        for i, r in enumerate(self.regions):
            if r.contains(az, el):
                return i
        return -1

    def index_of_attitude(self, R_WB: np.ndarray) -> int:
        """Index of the region of attitude ``R_WB`` (its up direction is the third row of R_WB)."""
        return self.index_of_direction(R_WB[2])

    def name_of_direction(self, v_B: np.ndarray) -> str:
        """Name of the region of an up direction or a hover force direction (body frame)."""
        return self.regions[self.index_of_direction(v_B)].name

    def name_of_attitude(self, R_WB: np.ndarray) -> str:
        """Name of the region of attitude ``R_WB``."""
        return self.regions[self.index_of_attitude(R_WB)].name

    def region(self, name: str) -> Region:
        """The region called ``name``."""
        for r in self.regions:
            if r.name == name:
                return r
        raise InputError(f"unknown region {name!r}; partition {self.name!r} has {', '.join(self.names)}")

    def to_dict(self) -> dict:
        """Plain-data form (as in the TOML file)."""
        return {"name": self.name, "region": [dataclasses.asdict(r) for r in self.regions]}


def partition_from_dict(data: dict, where: str = "partition") -> Partition:
    """Build a partition from its TOML/JSON table ``{name, region: [...]}``."""
    if not isinstance(data, dict):
        raise InputError(f"{where}: expected a table, got {type(data).__name__}")
    data = dict(data)
    raw = data.pop("region", None)
    if not isinstance(raw, list) or not raw:
        raise InputError(f"{where}: needs [[region]] tables")
    regions = tuple(from_mapping(Region, r, f"{where} region {i + 1}") for i, r in enumerate(raw))
    return from_mapping(Partition, {**data, "regions": regions}, where)


def load_partition(spec: str | Path = "paper") -> Partition:
    """Load a partition by preset name (``paper``) or TOML path."""
    text = str(spec)
    presets = resources.files("omnirotor") / "presets" / "regions"
    if "/" not in text and len(text) < 200 and (presets / f"{text}.toml").is_file():
        return partition_from_dict(load_toml(Path(str(presets / f"{text}.toml"))), f"partition {text}")
    return partition_from_dict(load_toml(Path(text)), text)
