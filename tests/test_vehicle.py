import math

import numpy as np
import pytest

from omnirotor.errors import InputError
from omnirotor.vehicle import (
    force_envelope,
    load_vehicle,
    max_zero_torque_force,
    preset_names,
    zero_moment_force_basis,
)

# SPEC §1.2, printed to 5 significant digits.
A_SPEC = np.array(
    [
        [-1.1491e-04, 0, 1.1491e-04, 0, 1.1491e-04, 0, -1.1491e-04, 0],
        [0, -1.1491e-04, 0, 1.1491e-04, 0, 1.1491e-04, 0, -1.1491e-04],
        [9.6418e-05] * 8,
        [1.0367e-05, 2.6415e-05, -1.0367e-05, -2.6415e-05, 1.3737e-05, 2.6415e-05, -1.3737e-05, -2.6415e-05],
        [-2.6415e-05, 1.3737e-05, 2.6415e-05, -1.3737e-05, -2.6415e-05, 1.0367e-05, 2.6415e-05, -1.0367e-05],
        [1.5777e-05, 1.2949e-05, 1.5777e-05, 1.2949e-05, -1.2949e-05, -1.5777e-05, -1.2949e-05, -1.5777e-05],
    ]
)


def spec_closed_form():
    """A_nom built directly from the SPEC §1.2 table, independently of the TOML preset."""
    a, l, cf, ct = math.radians(50), 0.125, 1.5e-4, 2.2e-6
    s = [-1, 1, 1, -1, 1, -1, -1, 1]
    k = [1, -1, 1, -1, 1, -1, 1, -1]
    corners = [
        (1, 1, 1),
        (-1, 1, 1),
        (-1, -1, 1),
        (1, -1, 1),
        (1, 1, -1),
        (-1, 1, -1),
        (-1, -1, -1),
        (1, -1, -1),
    ]
    cols = []
    for i in range(8):
        t = s[i] * a
        z = np.array([math.sin(t), 0, math.cos(t)]) if i % 2 == 0 else np.array([0, -math.sin(t), math.cos(t)])
        p = l * np.array(corners[i])
        cols.append(np.concatenate([cf * z, np.cross(p, cf * z) + k[i] * ct * z]))
    return np.array(cols).T


def test_omnirotor_allocation_matches_spec():
    A = load_vehicle("omnirotor").A_nom
    ref = spec_closed_form()
    assert np.max(np.abs(A - ref)) <= 1e-9 * np.max(np.abs(ref))
    np.testing.assert_allclose(A, A_SPEC, rtol=1e-4, atol=5e-10)  # the printed table's precision


def test_omnirotor_rank_condition_and_hover():
    v = load_vehicle()
    sv = np.linalg.svd(v.A_nom, compute_uv=False)
    assert np.sum(sv > 1e-12) == 6
    assert sv[0] / sv[-1] == pytest.approx(6.68, abs=0.01)
    np.testing.assert_allclose(sv, [2.73e-4, 2.30e-4, 2.30e-4, 5.81e-5, 5.81e-5, 4.08e-5], rtol=5e-3)
    u = v.hover_input()
    np.testing.assert_allclose(u, 20667, rtol=1e-4)
    np.testing.assert_allclose(v.A_nom @ u, [0, 0, v.weight, 0, 0, 0], atol=1e-9)


def test_force_envelope_matches_spec():
    env = force_envelope(load_vehicle(), n_directions=200)
    # SPEC §1.3: min over directions of the max zero-torque force 21.7 N, straight up 37.3 N.
    assert env.min_N == pytest.approx(21.7, abs=0.1)
    assert env.max_N == pytest.approx(37.3, abs=0.1)
    assert env.min_N / 15.94 == pytest.approx(1.36, abs=0.01)


def test_quadrotor_cannot_push_sideways_but_lifts():
    v = load_vehicle("quadrotor")
    assert np.linalg.matrix_rank(v.A_nom) == 4
    env = force_envelope(v, n_directions=60, refine=False)
    assert env.min_N == pytest.approx(0.0, abs=1e-9)
    up = max_zero_torque_force(v, [0, 0, 1])
    # the envelope samples the thrust axis itself: its maximum is the full thrust, not 0 N
    assert env.max_N == pytest.approx(up, rel=1e-6)
    assert zero_moment_force_basis(v.A_nom).shape == (3, 1)
    assert zero_moment_force_basis(load_vehicle().A_nom).shape == (3, 3)
    assert up == pytest.approx(4 * v.c_f * v.omega_max_hz**2, rel=1e-6)
    assert max_zero_torque_force(v, [1, 0, 0]) == pytest.approx(0.0, abs=1e-9)
    u = v.hover_input()
    assert np.all(u > 0) and np.allclose(u, u[0])


def test_hexarotor_is_fully_actuated():
    v = load_vehicle("hexarotor-tilted")
    assert np.linalg.matrix_rank(v.A_nom) == 6
    u = v.hover_input()
    assert np.all((u >= v.u_min) & (u <= v.u_max))


def test_presets_listed():
    assert {"omnirotor", "quadrotor", "hexarotor-tilted"} <= set(preset_names())


def write_vehicle(tmp_path, text):
    p = tmp_path / "v.toml"
    p.write_text(text)
    return p


BASE = """
name = "t"
mass = 1.0
inertia_diag = [0.01, 0.01, 0.01]
c_f = 1e-4
c_tau = 1e-6
omega_max_hz = 200.0
omega_min_hz = -200.0
{extra}
"""


def rotors(n=8, axis="[0.0, 0.0, 1.0]"):
    rng = np.random.default_rng(0)
    out = []
    for i in range(n):
        p = rng.uniform(-0.2, 0.2, 3)
        a = rng.normal(size=3) if axis == "random" else None
        ax = axis if a is None else f"[{a[0]}, {a[1]}, {a[2]}]"
        out.append(f"[[rotor]]\nposition = [{p[0]}, {p[1]}, {p[2]}]\naxis = {ax}\nspin = {1 if i % 2 else -1}\n")
    return "\n".join(out)


def test_custom_vehicle_file_loads(tmp_path):
    v = load_vehicle(write_vehicle(tmp_path, BASE.format(extra=rotors(axis="random"))))
    assert v.n_rotors == 8 and v.A_nom.shape == (6, 8)


@pytest.mark.parametrize(
    "extra,match",
    [
        (rotors(axis="[0.0, 0.0, 1.0]"), "rank"),  # all axes parallel -> rank 4 < declared 6
        (rotors(axis="random") + "\nbogus = 1", "unknown key"),
        ("", "rotor"),
    ],
)
def test_bad_vehicle_files(tmp_path, extra, match):
    with pytest.raises(InputError, match=match):
        load_vehicle(write_vehicle(tmp_path, BASE.format(extra=extra)))


@pytest.mark.parametrize(
    "field,value,match",
    [
        ("mass", "-1.0", "mass"),
        ("mass", "nan", "mass"),
        ("inertia_diag", "[0.01, 0.01, 0.05]", "triangle"),
        ("omega_min_hz", "300.0", "omega_min_hz"),
        ("c_f", "0.0", "c_f"),
    ],
)
def test_non_physical_parameters(tmp_path, field, value, match):
    text = BASE.format(extra=rotors(axis="random"))
    text = "\n".join(f"{field} = {value}" if line.startswith(f"{field} =") else line for line in text.splitlines())
    with pytest.raises(InputError, match=match):
        load_vehicle(write_vehicle(tmp_path, text))


def test_unknown_preset_and_missing_file(tmp_path):
    with pytest.raises(InputError, match="unknown vehicle preset"):
        load_vehicle("octo-nonsense")
    with pytest.raises(InputError, match="no such file"):
        load_vehicle(tmp_path / "missing.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("mass = [")
    with pytest.raises(InputError, match="not valid TOML"):
        load_vehicle(bad)
