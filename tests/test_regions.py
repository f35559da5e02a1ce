import math

import numpy as np
import pytest

from omnirotor.errors import InputError
from omnirotor.regions import azimuth_elevation, load_partition, partition_from_dict
from omnirotor.so3 import R_from_rpy, rot_x, rot_y, rot_z
from omnirotor.vehicle import fibonacci_sphere


def up(az_deg, el_deg):
    az, el = math.radians(az_deg), math.radians(el_deg)
    return np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])


@pytest.mark.parametrize(
    "az,el,name",
    [
        (0, 90, "R1"),
        (37, 61, "R1"),
        (0, 30, "R2"),
        (-90, 45, "R3"),
        (90, 45, "R4"),
        (180, 10, "R5"),
        (-170, 10, "R5"),
        (0, -80, "R6"),
        (10, -30, "R7"),
        (-100, -30, "R8"),
        (100, -30, "R9"),
        (170, -30, "R10"),
        # closed intervals, first match wins on shared borders
        (0, 60, "R1"),
        (45, 30, "R2"),
        (-45, 30, "R2"),
        (135, 30, "R4"),
        (0, 0, "R2"),
        (0, -60, "R6"),
    ],
)
def test_paper_regions(az, el, name):
    assert load_partition("paper").name_of_direction(up(az, el)) == name


def test_every_direction_has_a_region():
    p = load_partition()
    for v in fibonacci_sphere(3000):
        assert p.index_of_direction(v) >= 0


def test_attitude_region_is_that_of_gravity_up_in_body():
    p = load_partition()
    assert p.name_of_attitude(np.eye(3)) == "R1"
    # yaw does not change the region
    assert p.name_of_attitude(rot_z(2.0)) == "R1"
    # SPEC §3.3: sliding roll R = Rx(-theta) switches R1 -> R3 at 30 deg
    assert p.name_of_attitude(rot_x(math.radians(-29.9))) == "R1"
    assert p.name_of_attitude(rot_x(math.radians(-30.1))) == "R3"
    assert p.name_of_attitude(rot_x(math.radians(-45))) == "R3"
    assert p.name_of_attitude(rot_x(math.radians(45))) == "R4"
    assert p.name_of_attitude(rot_y(math.pi)) == "R6"


def test_region_of_force_matches_region_of_attitude():
    rng = np.random.default_rng(0)
    p = load_partition()
    for _ in range(200):
        R = R_from_rpy(*rng.uniform(-math.pi, math.pi, 3))
        f_B = R.T @ np.array([0, 0, 15.94])
        assert p.name_of_direction(f_B) == p.name_of_attitude(R)


def test_sampling_box_inside_region():
    rng = np.random.default_rng(1)
    p = load_partition()
    for r in p.regions:
        for _ in range(50):
            v = r.sample_up_direction(rng)
            assert p.name_of_direction(v) == r.name
            if r.sample_elevation_deg:
                _, el = azimuth_elevation(v)
                lo, hi = r.sample_elevation_deg
                assert lo - 1e-9 <= math.degrees(el) <= hi + 1e-9


def test_partition_is_data():
    two = {
        "name": "hemispheres",
        "region": [
            {"name": "top", "azimuth_deg": [[-180, 180]], "elevation_deg": [0, 90]},
            {"name": "bottom", "azimuth_deg": [[-180, 180]], "elevation_deg": [-90, 0]},
        ],
    }
    p = partition_from_dict(two)
    assert p.name_of_direction([0, 0.1, -1]) == "bottom"
    assert p.name_of_direction([1, 0, 0]) == "top"


def test_partition_with_a_hole_is_rejected():
    holey = {"name": "h", "region": [{"name": "top", "azimuth_deg": [[-180, 180]], "elevation_deg": [0, 90]}]}
    with pytest.raises(InputError, match="hole"):
        partition_from_dict(holey)
    with pytest.raises(InputError, match="azimuth"):
        partition_from_dict(
            {"name": "x", "region": [{"name": "a", "azimuth_deg": [[-200, 180]], "elevation_deg": [-90, 90]}]}
        )
