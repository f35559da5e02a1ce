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
