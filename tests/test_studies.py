"""Studies of issue 15 on shortened runs: truth hover pools, partitions compared, points per region."""

import json

import numpy as np
import pytest

from omnirotor.cli import main
from omnirotor.regions import load_partition
from omnirotor.regions_from_signs import partition_from_signs
from omnirotor.sim.aero import make_aero
from omnirotor.studies.hover_pool import HoverNoise, build_pool, draw
from omnirotor.studies.partitions import compare_partitions, even_counts
from omnirotor.studies.points_per_region import points_per_region_study, summarise
from omnirotor.vehicle import load_vehicle


@pytest.fixture(scope="module")
def vehicle():
    return load_vehicle("omnirotor")


def test_even_counts_spread_the_total():
    part = load_partition("paper")
    c = even_counts(part, 53)
    assert sum(c.values()) == 53 and max(c.values()) - min(c.values()) == 1


def test_pool_points_hold_the_truth_and_noise_perturbs_them(vehicle):
    aero = make_aero(vehicle)
    part = load_partition("paper")
    pool = build_pool(vehicle, aero, part, 3, np.random.default_rng(0))
    R, u = pool.R_WB["R3"][0], pool.u_hz2["R3"][0]
    assert part.name_of_attitude(R) == "R3"
    assert np.allclose(aero.wrench_B(u), np.r_[R.T @ [0, 0, vehicle.weight], 0, 0, 0], atol=1e-6)
    exact = draw(pool, vehicle, {"R3": 3}, HoverNoise(0.0, 0.0), np.random.default_rng(1))
    noisy = draw(pool, vehicle, {"R3": 3}, HoverNoise(1.0, 0.5), np.random.default_rng(1))
    order = np.argsort(exact.u_hz2[:, 0])
    assert np.allclose(exact.u_hz2[order], pool.u_hz2["R3"][np.argsort(pool.u_hz2["R3"][:, 0])], rtol=1e-12)
    assert not np.allclose(exact.u_hz2, noisy.u_hz2) and exact.region == ("R3",) * 3


def test_points_per_region_more_points_less_error(vehicle):
    r = points_per_region_study(vehicle, counts=(3, 5, 20), noises=("high",), reps=4, n_validation=60, workers=1)
    res = r["results"]["high"]
    assert res["20"]["mean"] < res["5"]["mean"] < res["3"]["mean"] < r["nominal_force_residual_rms_N"]
    for v in res.values():
        assert v["ci95"][0] <= v["mean"] <= v["ci95"][1] and v["n"] == 4
    json.dumps(r)  # JSON-able


def test_summarise_interval():
    s = summarise([1.0, 2.0, 3.0])
    assert s["mean"] == 2.0 and s["ci95"][0] < 2.0 < s["ci95"][1] and s["median"] == 2.0


def test_partitions_compared_with_a_sliding_run(vehicle):
    signs = partition_from_signs(vehicle, n_check=2000).partition
    r = compare_partitions(
        vehicle, {"signs": signs}, total_points=len(signs.regions) * 5, reps=2, n_validation=60, sliding=True
    )
    e = r["partitions"]["signs"]
    assert e["regions"] == len(signs.regions) and sum(e["points_per_region"].values()) == r["total_points"]
    assert e["force_residual_rms_N"]["mean"] < 0.5 * r["nominal"]["force_residual_rms_N"]
    assert e["bias_f_rms_N"]["mean"] < 0.5 * r["nominal"]["bias_f_rms_N"]
    s = e["sliding"]
    assert s["map_switches"] >= 1  # the slide leaves the upright region
    assert 0.0 <= s["contact_fraction"] <= 1.0


def test_too_many_regions_for_the_total_is_refused(vehicle):
    from omnirotor.errors import InputError

    with pytest.raises(InputError, match="at least 5"):
        compare_partitions(vehicle, {"paper": load_partition("paper")}, total_points=30, reps=1, sliding=False)


@pytest.mark.parametrize(
    "args,needle",
    [
        (["points-per-region", "--noise", "bogus"], "noise"),
        (["points-per-region", "--counts", "3,x"], "integers"),
        (["points-per-region", "--reps", "1"], "reps"),
        (["partitions", "--noise", "bogus"], "noise"),
        (["partitions", "--partition", "{tmp}/none.toml"], "none.toml"),
    ],
)
def test_study_cli_bad_input(tmp_path, capsys, args, needle):
    out = tmp_path / "study"
    code = main(["study"] + [a.format(tmp=tmp_path) for a in args] + ["--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and needle in err and err.count("\n") == 1
    assert not out.exists()


@pytest.mark.parametrize("command", ["points-per-region", "partitions", "torque-rows"])
def test_study_cli_refuses_a_file_as_out_folder(tmp_path, capsys, command):
    out = tmp_path / "study"
    out.write_text("kept\n")
    code = main(["study", command, "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and "not a folder" in err and err.count("\n") == 1
    assert out.read_text() == "kept\n"


def test_noise_names_in_the_help_are_the_noise_levels():
    from omnirotor.cli.cmd_study import NOISE_NAMES
    from omnirotor.studies.hover_pool import NOISE_LEVELS

    assert NOISE_NAMES == ", ".join(NOISE_LEVELS)
