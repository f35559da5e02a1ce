"""Regions from the hover sign pattern (issue 15, item 2): allocation, partition, file, CLI."""

import dataclasses
import json

import numpy as np
import pytest

from omnirotor.cli import main
from omnirotor.identification import IdentificationParams, identify
from omnirotor.regions import load_partition
from omnirotor.regions_from_signs import (
    hover_allocation,
    mismatch_fraction,
    partition_from_signs,
    sign_codes,
    write_partition_toml,
)
from omnirotor.vehicle import fibonacci_sphere, load_vehicle


@pytest.fixture(scope="module")
def vehicle():
    return load_vehicle("omnirotor")


@pytest.fixture(scope="module")
def coarse(vehicle):
    return partition_from_signs(vehicle, n_check=4000)  # the defaults: 4 bands, 2 %, 5 deg


def test_hover_allocation_is_the_least_norm_hover_input_where_no_bound_binds(vehicle):
    rng = np.random.default_rng(0)
    v = rng.standard_normal((50, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    u = hover_allocation(vehicle, v)
    for k in range(50):
        R = np.eye(3)
        # an attitude whose up direction is v: any rotation with third row v
        x = np.cross(v[k], [0.3, 0.5, 0.7])
        x /= np.linalg.norm(x)
        R = np.vstack([x, np.cross(v[k], x), v[k]])
        assert np.allclose(u[k], vehicle.hover_input(R), rtol=0, atol=1e-6)
        assert np.allclose(vehicle.A_nom @ u[k], np.r_[vehicle.weight * v[k], 0, 0, 0], atol=1e-9)


def test_bounded_allocation_respects_the_rotor_limits(vehicle):
    slow = dataclasses.replace(vehicle, omega_max_hz=150.0)  # hover needs up to ~203 Hz
    v = fibonacci_sphere(200)
    u = hover_allocation(slow, v)
    assert np.all(u <= slow.u_max + 1e-6) and np.all(u >= slow.u_min - 1e-6)
    assert np.any(np.isclose(np.abs(u), slow.u_max))  # some attitudes do saturate


def test_sign_code_flips_bit_i_across_rotor_i_great_circle(vehicle):
    P = np.linalg.pinv(vehicle.A_nom)[:, :3]
    for i in range(vehicle.n_rotors):
        n = P[i] / np.linalg.norm(P[i])
        helper = np.cross(n, [1.0, 0, 0]) if abs(n[0]) < 0.9 else np.cross(n, [0, 1.0, 0])
        on = helper / np.linalg.norm(helper)  # a point on rotor i's great circle
        plus, minus = on + 1e-3 * n, on - 1e-3 * n
        c_plus, c_minus = sign_codes(vehicle, np.array([plus, minus]))
        assert (c_plus >> i) & 1 == 0 and (c_minus >> i) & 1 == 1


def test_upright_and_inverted_are_one_region_each(vehicle, coarse):
    part = coarse.partition
    up_code = coarse.codes[part.index_of_direction(np.array([0, 0, 1.0]))]
    down_code = coarse.codes[part.index_of_direction(np.array([0, 0, -1.0]))]
    assert up_code == 0  # no rotor reversed upright
    assert down_code == 2**vehicle.n_rotors - 1  # every rotor reversed upside down


def test_partition_file_round_trip_and_reported_mismatch(vehicle, coarse, tmp_path):
    path = tmp_path / "signs.toml"
    write_partition_toml(path, coarse, vehicle)
    loaded = load_partition(path)  # covers the sphere, or load_partition raises
    assert loaded.names == coarse.partition.names
    miss, areas, n_patterns = mismatch_fraction(vehicle, loaded, coarse.codes, 4000)
    assert miss == pytest.approx(coarse.mismatch_frac)
    assert sum(areas) == pytest.approx(1.0)
    assert n_patterns > len(loaded.regions)  # the format cannot follow every face


def test_more_bands_never_cost_more_and_tiny_regions_are_merged(vehicle):
    costs = [partition_from_signs(vehicle, b, 0.0, 10.0, n_check=4000).mismatch_frac for b in (1, 2, 4)]
    assert costs[0] >= costs[1] >= costs[2]
    merged = partition_from_signs(vehicle, 4, 0.05, 10.0, n_check=4000)
    assert min(merged.area_frac) > 0.05 - 0.01  # grid columns vs the Fibonacci measure
    assert len(merged.partition.regions) < len(partition_from_signs(vehicle, 4, 0.0, 10.0, n_check=4000).codes)


def test_signs_follow_the_patterns_better_than_the_paper(vehicle, coarse):
    paper_miss, _, _ = mismatch_fraction(vehicle, load_partition("paper"), None, 4000)
    assert coarse.mismatch_frac < paper_miss


def test_identified_maps_carry_the_written_partition(vehicle, coarse, tmp_path):
    from omnirotor.sim.aero import make_aero
    from omnirotor.studies.hover_pool import HoverNoise, build_pool, draw
    from omnirotor.wrench_maps import load_wrench_maps

    path = tmp_path / "signs.toml"
    write_partition_toml(path, coarse, vehicle)
    part = load_partition(path)
    rng = np.random.default_rng(1)
    pool = build_pool(vehicle, make_aero(vehicle), part, 6, rng)
    data = draw(pool, vehicle, {n: pool.size(n) for n in part.names}, HoverNoise(0.0, 0.0), rng, label=False)
    maps = identify(data, vehicle, IdentificationParams(), part)  # regions from the force direction
    maps.save(tmp_path / "maps.json")
    back = load_wrench_maps(tmp_path / "maps.json")
    assert back.partition.names == part.names and set(back.regions) == set(part.names)


def test_cli_writes_toml_and_figure(tmp_path, capsys):
    out, fig = tmp_path / "r.toml", tmp_path / "r.png"
    code = main(["regions", "--from-signs", "--step", "10", "--out", str(out), "--figure", str(fig)])
    assert code == 0 and out.is_file() and fig.stat().st_size > 0
    assert "regions" in capsys.readouterr().out
    assert load_partition(out).name == "r"


@pytest.mark.parametrize(
    "args,needle",
    [
        (["--from-signs", "--bands", "0"], "bands"),
        (["--from-signs", "--step", "7"], "divide"),
        (["--from-signs", "--min-area-frac", "0.7"], "min-area-frac"),
        (["--figure", "{tmp}/f.png"], "need --from-signs"),
    ],
)
def test_cli_bad_input(tmp_path, capsys, args, needle):
    out = tmp_path / "r.toml"
    argv = ["regions"] + [a.format(tmp=tmp_path) for a in args]
    if "--from-signs" in argv:
        argv += ["--out", str(out)]
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2 and needle in err and err.count("\n") == 1
    assert not out.exists() and not (tmp_path / "f.png").exists()


def test_cli_refuses_unsafe_destinations_before_any_work(tmp_path, capsys):
    target = tmp_path / "target.toml"
    target.write_text("kept\n")
    link = tmp_path / "link.toml"
    link.symlink_to(target)
    folder = tmp_path / "folder.toml"
    folder.mkdir()
    cases = [
        (["--out", str(link)], "symbolic link"),
        (["--out", str(folder)], "folder"),
        (["--out", str(tmp_path / "r.toml"), "--figure", str(tmp_path / "r.jpg")], ".png"),
    ]
    for extra, needle in cases:
        code = main(["regions", "--from-signs", "--step", "10", *extra])
        err = capsys.readouterr().err
        assert code == 2 and needle in err and err.count("\n") == 1, (extra, err)
    assert target.read_text() == "kept\n" and link.is_symlink()
    assert not (tmp_path / "r.toml").exists() and not (tmp_path / "r.jpg").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["folder.toml", "link.toml", "target.toml"]  # no temp files


def test_cli_replacing_a_file_says_so(tmp_path, capsys):
    out = tmp_path / "r.toml"
    out.write_text("old\n")
    code = main(["regions", "--from-signs", "--step", "10", "--out", str(out), "--json"])
    cap = capsys.readouterr()
    assert code == 0 and load_partition(out).name == "r"
    assert "--out" in cap.err and "replaced" in cap.err and cap.err.count("\n") == 1
    assert json.loads(cap.out)["out"] == str(out)
