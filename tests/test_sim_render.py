"""Pictures and videos of the simulator: ``omnirotor render`` and the video recorder."""

import os

import numpy as np
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")

from omnirotor.cli import main  # noqa: E402
from omnirotor.errors import InputError  # noqa: E402
from omnirotor.messages import RotorCommand  # noqa: E402
from omnirotor.sim import SimParams, Simulator, VideoRecorder, render_scene  # noqa: E402
from omnirotor.vehicle import load_vehicle  # noqa: E402


@pytest.fixture(scope="module")
def gl():
    """Skip when this machine cannot open an offscreen GL context."""
    try:
        render_scene("free", width=32, height=32)
    except InputError as exc:
        pytest.skip(f"no offscreen GL: {exc}")


def test_cli_render_writes_a_non_blank_png(gl, tmp_path):
    import imageio.v3 as iio

    out = tmp_path / "pics" / "wall.png"
    assert main(["render", "wall", "--out", str(out), "--width", "160", "--height", "120"]) == 0
    img = iio.imread(out)
    assert img.shape == (120, 160, 3)
    assert img.std() > 10  # not a blank frame
    assert len(np.unique(img.reshape(-1, 3), axis=0)) > 50
    assert [p.name for p in out.parent.iterdir()] == ["wall.png"]  # no temporary file left


def test_render_shows_the_scene_object(gl):
    free = render_scene("free", width=160, height=120).astype(float)
    wall = render_scene("wall", width=160, height=120).astype(float)
    assert np.abs(free - wall).mean() > 5  # the wall changes the picture


def test_cli_render_bad_input_exits_2_and_writes_nothing(tmp_path, capsys):
    out = tmp_path / "x.png"
    assert main(["render", "moon", "--out", str(out)]) == 2
    assert "unknown scene" in capsys.readouterr().err
    assert main(["render", "wall", "--out", str(out), "--vehicle", "no-such-vehicle"]) == 2
    assert main(["render", "wall", "--out", str(tmp_path / "x.jpg")]) == 2
    assert main(["render", "wall", "--out", str(out), "--width", "0"]) == 2
    assert list(tmp_path.iterdir()) == []


def test_video_recorder_writes_an_mp4(gl, tmp_path):
    import imageio.v3 as iio

    sim = Simulator(load_vehicle("omnirotor"), "pipe", SimParams())
    path = tmp_path / "run.mp4"
    cmd = RotorCommand(0.0, sim.hover_speeds_hz())
    with VideoRecorder(sim, path, fps=50, width=96, height=64) as rec:
        rec.capture(sim)
        for _ in range(100):
            sim.step(cmd)
            rec.capture(sim)
        assert not path.exists()  # only written on close
    assert rec.frames == 6  # t = 0, 0.02, ..., 0.1 s
    frames = iio.imread(path)
    assert frames.shape == (6, 64, 96, 3)
    assert frames.std() > 5
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.mp4"]


def test_video_recorder_discards_on_error(gl, tmp_path):
    sim = Simulator(load_vehicle("omnirotor"), "free", SimParams())
    path = tmp_path / "bad.mp4"
    with pytest.raises(RuntimeError), VideoRecorder(sim, path, width=64, height=48) as rec:
        rec.capture()
        raise RuntimeError("run failed")
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(InputError):
        VideoRecorder(sim, path, width=65, height=48)


def test_stepped_model_has_small_textures_and_steps_as_the_rendered_one():
    import mujoco

    from omnirotor.sim.model import TEXTURE_PX, build_mjcf

    sim = Simulator(load_vehicle("omnirotor"), scene="wall")
    small, full = sim.model, sim.render_model
    assert sim.render_model is full  # compiled once
    assert sorted(full.tex_width) == sorted(TEXTURE_PX) and max(small.tex_width) == 2
    sizes = ("ngeom", "nbody", "nq", "nsensordata", "nmat")
    assert [getattr(small, k) for k in sizes] == [getattr(full, k) for k in sizes]
    # the textures change nothing simulated: the same pushes give the same trajectory, bit for bit, falling onto
    # the floor and bouncing on it
    p = SimParams()
    models = [
        mujoco.MjModel.from_xml_string(build_mjcf(sim.vehicle, "wall", p.scene, p.dt / p.substeps, textures=t))
        for t in (False, True)
    ]
    datas = [mujoco.MjData(m) for m in models]
    body = mujoco.mj_name2id(models[0], mujoco.mjtObj.mjOBJ_BODY, "vehicle")
    contacts = []
    for m, d in zip(models, datas, strict=True):
        d.qpos[:3] = sim.data.qpos[:3]
        d.qpos[3:7] = sim.data.qpos[3:7]
        n = 0
        for k in range(900 * p.substeps):  # 0.9 s of pushes, whatever the physics step
            d.xfrc_applied[body, :3] = (0.0, 3.0 * np.sin(0.01 * k / p.substeps), 0.0)
            mujoco.mj_step(m, d)
            n += d.ncon
        contacts.append(n)
    assert contacts[0] == contacts[1] > 0
    assert np.array_equal(datas[0].qpos, datas[1].qpos) and np.array_equal(datas[0].sensordata, datas[1].sensordata)
