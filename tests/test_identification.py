import json

import numpy as np
import pytest
import scipy.io as sio

from omnirotor.errors import InputError
from omnirotor.identification import (
    HoverData,
    IdentificationParams,
    force_residual_rms,
    identify,
    load_csv,
    load_hover_data,
    load_mat,
    solve_map,
    solve_map_lsq,
    write_csv,
)
from omnirotor.regions import load_partition
from omnirotor.so3 import R_from_rpy
from omnirotor.vehicle import load_vehicle
from omnirotor.wrench_maps import load_wrench_maps

VEHICLE = load_vehicle("omnirotor")
DELTA = 3e-5


def authors_map(folder, k):
    s = sio.loadmat(folder / f"wrenchMap_reg{k}.mat", squeeze_me=True, struct_as_record=False)["wMapStruct"]
    return s.wrenchMap[:, :, 3]  # delta index 3 = 3e-5


def test_real_data_reproduces_authors_maps(flight_data):
    maps = identify(load_hover_data([flight_data], VEHICLE), VEHICLE, IdentificationParams(delta=DELTA))
    assert sorted(maps.regions) == ["R1", "R3", "R4"]
    for k in (1, 3, 4):
        A = maps.regions[f"R{k}"].A
        err = np.abs(A[:3] - authors_map(flight_data, k)[:3]).max() / DELTA
        assert err < 0.01, f"R{k}: force rows differ from the authors' by {err:.2e} x delta"
        # torque rows stay at nominal (almost unweighted, tie-breaker)
        assert np.abs(A[3:] - VEHICLE.A_nom[3:]).max() < 2e-7


def test_real_data_residuals_match_readme(flight_data):
    # shared data README: nominal 1.86 / 2.41 / 2.33 N, authors' maps 0.334 / 0.347 / 0.354 N
    maps = identify(load_hover_data([flight_data], VEHICLE), VEHICLE)
    expect = {"R1": (14, 1.86, 0.334), "R3": (9, 2.41, 0.347), "R4": (16, 2.33, 0.354)}
    for name, (n, nom, ident) in expect.items():
        e = maps.regions[name]
        assert e.points == n
        assert e.nominal_force_residual_rms_N == pytest.approx(nom, abs=0.005)
        assert e.force_residual_rms_N == pytest.approx(ident, abs=0.0005)
    # SPEC §3.5: the global map fits all regions better than nominal, worse than each region's own map
    g = maps.global_
    assert g.points == 39
    assert (
        max(e.force_residual_rms_N for e in maps.regions.values())
        < g.force_residual_rms_N
        < g.nominal_force_residual_rms_N
    )


def test_real_data_every_point_in_its_file_region(flight_data):
    part = load_partition()
    for k in (1, 3, 4):
        d = load_mat(flight_data / f"wrenchMap_reg{k}.mat")
        assert {part.name_of_direction(w[:3]) for w in d.w_B} == {f"R{k}"}


def test_daqp_agrees_with_bvls_oracle(flight_data):
    d = load_mat(flight_data / "wrenchMap_reg3.mat")
    for delta in (1e-6, 1e-5, 3e-5, 1e-4):
        p = IdentificationParams(delta=delta)
        A1, A2 = solve_map(d, VEHICLE.A_nom, p), solve_map_lsq(d, VEHICLE.A_nom, p)
        assert np.abs(A1 - A2).max() < 1e-6 * delta
        assert np.all(np.abs(A1 - VEHICLE.A_nom) <= delta * (1 + 1e-9))


def synthetic_points(A_true, n, rng, region_rpy=None):
    """Hover points of a vehicle whose true map is A_true, at random attitudes."""
    Rs, us = [], []
    pinv = np.linalg.pinv(A_true)
    for _ in range(n):
        rpy = rng.uniform(-0.3, 0.3, 3) if region_rpy is None else np.asarray(region_rpy) + rng.uniform(-0.15, 0.15, 3)
        R = R_from_rpy(*rpy)
        w = np.concatenate([R.T @ [0, 0, VEHICLE.weight], np.zeros(3)])
        # exact hover inputs under the true map, plus a null-space excursion so all rotors vary independently
        null = np.linalg.svd(A_true)[2][-2:]
        u = pinv @ w + null.T @ rng.normal(0, 3000, 2)
        Rs.append(R)
        us.append(u)
    return Rs, np.array(us)


def test_synthetic_recovery_of_perturbed_map():
    """With inputs that excite every rotor (e.g. a force-sensor rig), a perturbed map inside the box is recovered."""
    rng = np.random.default_rng(7)
    A_true = VEHICLE.A_nom.copy()
    A_true[:3] *= 1 + rng.uniform(-0.1, 0.15, size=(3, 8))  # force rows off by up to 15 %, within delta
    u = rng.uniform(-30000, 30000, size=(30, 8))
    data = HoverData(u, u @ A_true.T, ("",) * 30, ("synthetic",) * 30)
    A = solve_map(data, VEHICLE.A_nom, IdentificationParams(delta=3e-5))
    assert np.abs(A[:3] - A_true[:3]).max() < 1e-4 * 3e-5
    assert force_residual_rms(data, A) < 1e-6
    assert force_residual_rms(data, VEHICLE.A_nom) > 0.5
    # a box too small to reach the truth ends on its bounds and fits worse
    small = solve_map(data, VEHICLE.A_nom, IdentificationParams(delta=1e-6))
    assert np.abs(small[:3] - VEHICLE.A_nom[:3]).max() == pytest.approx(1e-6)
    assert force_residual_rms(data, small) > 0.1


def test_synthetic_hover_points_fit_and_generalise():
    """Hover data (zero moment) fix A_1 on the hover subspace: the map then predicts hover at new attitudes."""
    rng = np.random.default_rng(8)
    A_true = VEHICLE.A_nom.copy()
    A_true[:3] *= 1.12
    Rs, u = synthetic_points(A_true, 15, rng)
    w = np.array([np.concatenate([R.T @ [0, 0, VEHICLE.weight], np.zeros(3)]) for R in Rs])
    data = HoverData(u, w, ("",) * 15, ("s",) * 15)
    A = solve_map(data, VEHICLE.A_nom, IdentificationParams(delta=3e-5))
    assert force_residual_rms(data, A) < 1e-3
    Rs2, u2 = synthetic_points(A_true, 10, np.random.default_rng(9))
    w2 = np.array([np.concatenate([R.T @ [0, 0, VEHICLE.weight], np.zeros(3)]) for R in Rs2])
    new = HoverData(u2, w2, ("",) * 10, ("s",) * 10)
    assert force_residual_rms(new, A) < 0.02 * force_residual_rms(new, VEHICLE.A_nom)


def test_csv_roundtrip_and_region_override(tmp_path):
    rng = np.random.default_rng(3)
    Rs, u = synthetic_points(VEHICLE.A_nom, 12, rng)
    omega = np.sign(u) * np.sqrt(np.abs(u))
    write_csv(tmp_path / "h.csv", Rs, omega)
    d = load_csv(tmp_path / "h.csv", VEHICLE)
    np.testing.assert_allclose(d.u_hz2, u, rtol=1e-6)
    np.testing.assert_allclose(d.w_B[:, :3], [R.T @ [0, 0, VEHICLE.weight] for R in Rs], atol=1e-6)
    maps = identify(d, VEHICLE)
    assert set(maps.regions) == {"R1"}
    maps = identify(d, VEHICLE, region="R7")
    assert set(maps.regions) == {"R7"} and maps.regions["R7"].points == 12


def test_csv_rpy_and_measured_wrench(tmp_path):
    p = tmp_path / "rpy.csv"
    speeds = ",".join(f"omega{i}_hz" for i in range(1, 9))
    rows = [f"roll_deg,pitch_deg,yaw_deg,{speeds},fx_N,fy_N,fz_N,mx_Nm,my_Nm,mz_Nm"]
    rows.append("10,0,0," + ",".join(["140"] * 8) + ",1,2,3,0,0,0")
    p.write_text("\n".join(rows) + "\n")
    d = load_csv(p, VEHICLE)
    np.testing.assert_allclose(d.w_B[0], [1, 2, 3, 0, 0, 0])
    np.testing.assert_allclose(d.u_hz2[0], 140.0**2)


def test_wrench_map_file_roundtrip(tmp_path, flight_data):
    maps = identify(load_hover_data([flight_data], VEHICLE), VEHICLE)
    maps.save(tmp_path / "m.json")
    back = load_wrench_maps(tmp_path / "m.json", n_rotors=8)
    for name in maps.regions:
        np.testing.assert_array_equal(back.regions[name].A, maps.regions[name].A)
    np.testing.assert_array_equal(back.global_.A, maps.global_.A)
    assert back.delta == maps.delta
    data = json.loads((tmp_path / "m.json").read_text())
    assert {"delta", "nominal", "global", "regions"} <= set(data)
    assert np.asarray(data["regions"]["R1"]["A"]).shape == (6, 8)


@pytest.mark.parametrize(
    "mutate,match",
    [
        (lambda d: d.update(schema="x"), "schema"),
        (lambda d: d.update(version=99), "version"),
        (lambda d: d["regions"]["R1"].update(A=[[1.0] * 8] * 5), "shape"),
        (lambda d: d["regions"]["R1"]["A"][0].__setitem__(0, float("nan")), "NaN"),
        (lambda d: d["regions"].update(R99=d["regions"]["R1"]), "unknown region"),
    ],
)
def test_bad_wrench_map_files(tmp_path, flight_data, mutate, match):
    maps = identify(load_hover_data([flight_data], VEHICLE), VEHICLE)
    data = maps.to_dict()
    mutate(data)
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(data))
    with pytest.raises(InputError, match=match):
        load_wrench_maps(p)


def test_too_few_points_and_bad_delta():
    rng = np.random.default_rng(0)
    Rs, u = synthetic_points(VEHICLE.A_nom, 4, rng)
    w = np.array([np.concatenate([R.T @ [0, 0, VEHICLE.weight], np.zeros(3)]) for R in Rs])
    with pytest.raises(InputError, match="at least 5"):
        identify(HoverData(u, w, ("",) * 4, ("s",) * 4), VEHICLE)
    for bad in (0.0, -1e-5, float("nan"), float("inf")):
        with pytest.raises(InputError, match="delta"):
            IdentificationParams(delta=bad)


@pytest.mark.parametrize(
    "content,match",
    [
        ("", "empty"),
        ("qw,qx,qy,qz\n1,0,0,0\n", "missing rotor-speed"),
        (
            "qw,qx,qy,qz," + ",".join(f"omega{i}_hz" for i in range(1, 9)) + "\n1,0,0,0," + ",".join(["nan"] * 8),
            "not finite",
        ),
        (
            "qw,qx,qy,qz," + ",".join(f"omega{i}_hz" for i in range(1, 9)) + "\n2,0,0,0," + ",".join(["100"] * 8),
            "not unit",
        ),
        (
            "qw,qx,qy,qz," + ",".join(f"omega{i}_hz" for i in range(1, 9)) + "\n1,0,0,0,abc" + ",1" * 7,
            "not a number",
        ),
        ("qw,qx,qy,qz,foo," + ",".join(f"omega{i}_hz" for i in range(1, 9)) + "\n", "unknown column"),
    ],
)
def test_bad_csv(tmp_path, content, match):
    p = tmp_path / "bad.csv"
    p.write_text(content)
    with pytest.raises(InputError, match=match):
        load_csv(p, VEHICLE)


def test_bad_files(tmp_path):
    junk = tmp_path / "junk.mat"
    junk.write_bytes(b"\x00garbage" * 20)
    with pytest.raises(InputError, match="MATLAB"):
        load_mat(junk)
    with pytest.raises(InputError, match="no such file"):
        load_hover_data([tmp_path / "missing.mat"], VEHICLE)
    empty = tmp_path / "empty_dir"
    empty.mkdir()
    with pytest.raises(InputError, match=r"folder holds no \.mat, \.csv or \.ulg hover data"):
        load_hover_data([empty], VEHICLE)
