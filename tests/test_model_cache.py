"""A run's plant built from what the worker kept equals the plant built afresh (issue #16, item 2: set-up per run).

:func:`omnirotor.sim.model_cache.compiled_model` compiles a kept :class:`mujoco.MjSpec` with each run's mass and
inertia; SPEC §7's truth model keeps its rotor pairs' jet profiles per rotor geometry; the tasks no longer reset
their plant at the scene's start before the run resets it at the trajectory's. None may change a number.
Compared here: every array and every ``opt``/``stat``/``vis`` value of the two models, the truth model's wrench,
and every metric of perturbed campaign runs flown both ways.
"""

import dataclasses

import mujoco
import numpy as np
import pytest

import omnirotor.experiments.tasks.common as tasks
import omnirotor.sim.aero as aero
import omnirotor.sim.simulator as simulator
from omnirotor.experiments.campaigns.runner import execute_run, load_campaign, run_options
from omnirotor.sim import model_cache
from omnirotor.sim.model import build_mjcf
from omnirotor.sim.params import AeroParams, SimParams
from omnirotor.vehicle import load_vehicle
from test_campaign_identical import PERTURBED, comparable

V = load_vehicle("omnirotor")
DT = SimParams().dt / SimParams().substeps


def fresh_model(vehicle, scene, params, timestep):
    """The model as the simulator built it before the cache: its MJCF generated and compiled."""
    return mujoco.MjModel.from_xml_string(build_mjcf(vehicle, scene, params, timestep, textures=False))


def model_values(m: mujoco.MjModel) -> dict[str, np.ndarray]:
    """Every array of ``m`` and every number of its ``opt``, ``stat`` and ``vis`` structs, by name."""
    out = {name: getattr(m, name) for name in dir(m) if not name.startswith("_")}
    out = {k: v for k, v in out.items() if isinstance(v, np.ndarray)}
    for sub in ("opt", "stat"):
        s = getattr(m, sub)
        for name in dir(s):
            v = getattr(s, name)
            if not name.startswith("_") and isinstance(v, (np.ndarray, float, int)):
                out[f"{sub}.{name}"] = np.asarray(v)
    for group in ("global_", "quality", "headlight", "map", "scale", "rgba"):
        g = getattr(m.vis, group)
        for name in dir(g):
            v = getattr(g, name)
            if not name.startswith("_") and isinstance(v, (np.ndarray, float, int)):
                out[f"vis.{group}.{name}"] = np.asarray(v)
    return out


def perturbed(rng: np.random.Generator, vehicle=V):
    """``vehicle`` with its mass and principal inertia off as the default campaign draws them."""
    J = tuple(j * (1.0 + 0.1 * rng.standard_normal()) for j in vehicle.inertia_diag)
    return dataclasses.replace(vehicle, mass=vehicle.mass * (1.0 + 0.03 * rng.standard_normal()), inertia_diag=J)


@pytest.mark.parametrize(
    ("scene", "compliant"), [("free", True), ("free", False), ("pipe", True), ("peg-in-hole", True)]
)
def test_cached_model_equals_the_compiled_mjcf_array_for_array(scene, compliant):
    model_cache.clear()
    rng = np.random.default_rng(11)
    params = dataclasses.replace(SimParams().scene, tool_compliant=compliant)
    for _ in range(8):  # the first call parses, the others reuse the parsed model
        v = perturbed(rng)
        got, want = (
            model_values(model_cache.compiled_model(v, scene, params, DT)),
            model_values(fresh_model(v, scene, params, DT)),
        )
        assert sorted(got) == sorted(want)
        differ = [k for k in want if not np.array_equal(got[k], want[k], equal_nan=True)]
        assert not differ, f"the cached model differs from the run's own MJCF in {differ}"
    assert len(model_cache._specs) == 1  # one parsed model served all eight vehicles


def test_cache_keeps_every_other_parameter_apart():
    model_cache.clear()
    params = SimParams().scene
    moved = dataclasses.replace(params, pipe_centre=tuple(x + 0.05 for x in params.pipe_centre))
    for p in (params, moved):
        got, want = (
            model_values(model_cache.compiled_model(V, "pipe", p, DT)),
            model_values(fresh_model(V, "pipe", p, DT)),
        )
        assert all(np.array_equal(got[k], want[k], equal_nan=True) for k in want)
    assert len(model_cache._specs) == 2
    assert not np.array_equal(
        model_cache.compiled_model(V, "pipe", params, DT).geom_pos,
        model_cache.compiled_model(V, "pipe", moved, DT).geom_pos,
    )


def test_mass_and_inertia_reach_the_mjcf_through_the_vehicle_inertial_alone():
    # The cache's key leaves out the mass and the inertia: nothing else of the MJCF may depend on them.
    heavy = perturbed(np.random.default_rng(3))
    for scene in ("free", "wall", "peg-in-hole"):
        a = build_mjcf(V, scene, SimParams().scene, DT, textures=False).splitlines()
        b = build_mjcf(heavy, scene, SimParams().scene, DT, textures=False).splitlines()
        changed = [(x, y) for x, y in zip(a, b, strict=True) if x != y]
        assert len(changed) == 1 and changed[0][0].strip().startswith('<inertial pos="0 0 0" mass=')


INERTIA = """
[vary.inertia_error]
dist = "normal"
std = 0.10
"""
"""Added to the default campaign's parameters (those of ``test_campaign_identical``): the inertia edits the model."""


@pytest.mark.parametrize(
    ("task", "duration", "extra"),
    [
        ("hover", 2.0, ""),
        ("point-contact", 4.0, '[vary.scene_offset_y]\ndist = "uniform"\nlow = -0.01\nhigh = 0.01'),
    ],
)
def test_perturbed_runs_equal_runs_on_freshly_built_plants(tmp_path, monkeypatch, task, duration, extra):
    camp = tmp_path / "c.toml"
    camp.write_text(PERTURBED.format(task=task, duration=duration) + INERTIA + extra)
    spec = load_campaign(camp)
    jobs = [run_options(spec, i) for i in range(3)]
    model_cache.clear()
    cached = [execute_run(job) for job in jobs]
    assert all(r["status"] == "ok" for r in cached)

    # The plant as built before: each run's MJCF compiled, and reset at the scene's start on construction.
    monkeypatch.setattr(simulator, "compiled_model", fresh_model)
    plant = tasks.plant_simulator
    monkeypatch.setattr(tasks, "plant_simulator", lambda *a, reset=True, **k: plant(*a, reset=True, **k))
    fresh = [execute_run(job) for job in jobs]
    for i, (a, b) in enumerate(zip(cached, fresh, strict=True)):
        assert a["params"]["mass_error"] != 0.0 and a["params"]["inertia_error"] != 0.0
        assert comparable(a["metrics"]) == comparable(b["metrics"]), f"run {i} differs from its fresh plant"


def test_interference_truth_from_kept_profiles_equals_one_built_afresh():
    rng = np.random.default_rng(5)
    u = rng.uniform(-1.0, 1.0, (20, V.n_rotors)) * 1.5e4  # both spin directions [Hz²]
    for tilt in (0.0, 3.0):  # nominal axes (shared by all runs), then a new airframe's
        params = [AeroParams(model="spec7", gamma=g, gain_error_std=0.03, tilt_error_std_deg=tilt, error_seed=s)
                  for g, s in ((3.0, 1), (7.5, 2))]  # fmt: skip
        aero._profiles.clear()
        fresh = [aero.make_aero(V, p) for p in params]  # each the first of its geometry (cleared between)
        for f in fresh:
            aero._profiles.clear()
            f2 = aero.make_aero(V, f.params)
            assert np.array_equal(f2._K2, f._K2)
        kept = [aero.make_aero(V, p) for p in params]  # the second from the first's profiles when they agree
        for a, b in zip(kept, fresh, strict=True):
            assert np.array_equal(a._K2, b._K2)
            assert all(np.array_equal(a.wrench_B(x), b.wrench_B(x)) for x in u)
        assert len(aero._profiles) == (1 if tilt == 0.0 else 2)
    with pytest.raises(ValueError, match="read-only"):
        next(iter(aero._profiles.values()))[0][0, 1] = 1.0
