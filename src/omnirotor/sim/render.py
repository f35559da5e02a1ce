"""Offscreen pictures and videos of the simulator (MuJoCo renderer, EGL by default).

* :func:`render_frame`: an RGB image of a simulator's current state.
* :func:`render_scene`: a scene with the vehicle at its default start pose (``omnirotor render``).
* :class:`VideoRecorder`: frames at a fixed rate while a run steps, written as an MP4 (imageio-ffmpeg) through
  a temporary file, so a failed run leaves nothing half-written.

The default camera looks at the midpoint between the vehicle and the scene's contact anchor, from the side
(perpendicular to the line joining them, 30 deg off), far enough to frame both; it can track the vehicle.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import mujoco  # noqa: E402  (the GL backend must be chosen before the import)
import numpy as np  # noqa: E402

from omnirotor.errors import InputError  # noqa: E402
from omnirotor.safe_io import commit_temp, reserve_temp  # noqa: E402
from omnirotor.sim.params import SimParams  # noqa: E402
from omnirotor.sim.simulator import Simulator  # noqa: E402
from omnirotor.vehicle import VehicleParams, load_vehicle  # noqa: E402

__all__ = ["render_frame", "render_scene", "VideoRecorder", "default_camera", "MAX_SIZE"]

MAX_SIZE = 4096
"""Largest image side [px]."""
_VIEW_OFFSET_DEG = 30.0
_ELEVATION_DEG = -18.0
_MIN_DISTANCE_PER_SPAN = 1.4
"""Closest camera distance over the vehicle's span (1.4 m for the Omnirotor and its 0.5 m rod)."""


def _check_size(width: int, height: int) -> None:
    for label, v in (("width", width), ("height", height)):
        if not isinstance(v, (int, np.integer)) or not 16 <= v <= MAX_SIZE:
            raise InputError(f"{label} must be an integer in [16, {MAX_SIZE}], got {v!r}")


def _anchor(sim: Simulator) -> np.ndarray:
    """The scene's contact anchor, or the vehicle's position in free space."""
    a = sim.scene
    if a.surface_point_W is not None:
        return np.asarray(a.surface_point_W, dtype=float)
    return sim.data.qpos[:3].copy()


def default_camera(sim: Simulator) -> mujoco.MjvCamera:
    """A free camera framing the vehicle and the scene's contact object."""
    p = sim.data.qpos[:3].copy()
    target = _anchor(sim)
    line = target - p
    horiz = math.hypot(line[0], line[1])
    base_az = math.degrees(math.atan2(line[1], line[0])) if horiz > 1e-6 else 90.0
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_FREE
    cam.lookat[:] = 0.5 * (p + target)
    v = sim.vehicle
    reach = np.linalg.norm(v.positions_B, axis=1).max() + 0.5 * v.propeller_diameter
    span = 2.0 * max(float(reach), float(np.linalg.norm(v.p_E_B_array)))
    cam.distance = max(_MIN_DISTANCE_PER_SPAN * span, 1.3 * float(np.linalg.norm(line)) + 0.8 * span)
    # Look perpendicular to the line vehicle -> anchor, a little off-axis.
    cam.azimuth = base_az - 90.0 + _VIEW_OFFSET_DEG
    cam.elevation = _ELEVATION_DEG
    return cam


def _track(sim: Simulator, cam: mujoco.MjvCamera) -> None:
    cam.lookat[:] = 0.5 * (sim.data.qpos[:3] + _anchor(sim))


def _make_renderer(model: mujoco.MjModel, width: int, height: int) -> mujoco.Renderer:
    model.vis.global_.offwidth = max(int(model.vis.global_.offwidth), width)
    model.vis.global_.offheight = max(int(model.vis.global_.offheight), height)
    try:
        return mujoco.Renderer(model, height=height, width=width)
    except Exception as exc:  # GL context errors come as various types
        backend = os.environ.get("MUJOCO_GL")
        raise InputError(f"cannot open an offscreen renderer (MUJOCO_GL={backend}): {exc}") from None


def render_frame(
    sim: Simulator, width: int = 960, height: int = 720, camera: mujoco.MjvCamera | None = None
) -> np.ndarray:
    """An RGB image of the simulator's current state.

    Args:
        sim: the simulator.
        width: [px].
        height: [px].
        camera: the camera (default :func:`default_camera`).

    Returns:
        (height, width, 3) uint8 image.
    """
    _check_size(width, height)
    renderer = _make_renderer(sim.render_model, width, height)
    try:
        renderer.update_scene(sim.data, camera=camera or default_camera(sim))
        return renderer.render().copy()
    finally:
        renderer.close()


def render_scene(
    scene: str = "wall",
    vehicle: VehicleParams | str | None = None,
    width: int = 960,
    height: int = 720,
    params: SimParams | None = None,
) -> np.ndarray:
    """A picture of a scene with the vehicle at its default start pose.

    Args:
        scene: one of :data:`omnirotor.sim.SCENES`.
        vehicle: a vehicle, a preset name or a vehicle file (default the Omnirotor).
        width: [px].
        height: [px].
        params: simulator parameters (scene geometry).

    Returns:
        (height, width, 3) uint8 image.

    Raises:
        InputError: unknown scene or vehicle, bad size, no GL context.
    """
    _check_size(width, height)
    v = vehicle if isinstance(vehicle, VehicleParams) else load_vehicle(vehicle or "omnirotor")
    sim = Simulator(v, scene, params)
    return render_frame(sim, width, height)


class VideoRecorder:
    """Captures frames of a simulator at a fixed rate and writes an MP4.

    Call :meth:`capture` after every step (it renders only when a frame is due) and :meth:`close` at the end;
    or use it as a context manager. The file appears only when :meth:`close` succeeds.

    Args:
        sim: the simulator.
        path: the MP4 file to write.
        fps: frame rate [1/s] in simulated time.
        width: [px], even.
        height: [px], even.
        track: keep the camera centred between the vehicle and the scene's anchor.
    """

    def __init__(
        self,
        sim: Simulator,
        path: str | Path,
        fps: float = 30.0,
        width: int = 640,
        height: int = 480,
        track: bool = True,
    ) -> None:
        import imageio.v2 as imageio

        _check_size(width, height)
        if width % 2 or height % 2:
            raise InputError(f"video width and height must be even, got {width}x{height}")
        if not (math.isfinite(fps) and 1.0 <= fps <= 240.0):
            raise InputError(f"fps must lie in [1, 240], got {fps}")
        self.sim = sim
        self.path = Path(path)
        self.fps = float(fps)
        self.track = track
        self.frames = 0
        self._tmp = reserve_temp(self.path, "--video")  # exclusive, unpredictable; its folder made
        try:
            self._renderer = _make_renderer(sim.render_model, width, height)
        except BaseException:
            self._tmp.unlink(missing_ok=True)
            raise
        self._camera = default_camera(sim)
        self._next_t = sim.t
        self._period = 1.0 / self.fps
        try:
            self._writer = imageio.get_writer(
                self._tmp,
                format="FFMPEG",
                fps=self.fps,
                codec="libx264",
                macro_block_size=2,
                ffmpeg_log_level="error",
                output_params=["-pix_fmt", "yuv420p"],
            )
        except Exception as exc:
            self._renderer.close()
            self._tmp.unlink(missing_ok=True)
            raise InputError(f"{self.path}: cannot start the video writer ({exc})") from None
        self._closed = False

    def capture(self, sim: Simulator | None = None) -> bool:
        """Render and append a frame if one is due at the simulator's time; returns True if it did.

        Args:
            sim: ignored unless given, then it must be the recorder's simulator (so the recorder fits any
                ``capture(sim)`` hook).
        """
        if sim is not None and sim is not self.sim:
            raise InputError("VideoRecorder.capture: this recorder films another simulator")
        if self._closed or self.sim.t + 1e-9 < self._next_t:
            return False
        if self.track:
            _track(self.sim, self._camera)
        self._renderer.update_scene(self.sim.data, camera=self._camera)
        self._writer.append_data(self._renderer.render())
        self.frames += 1
        self._next_t += self._period
        while self._next_t <= self.sim.t:  # after a jump in time, do not burst
            self._next_t += self._period
        return True

    def close(self) -> Path:
        """Finish the file and move it into place; returns its path."""
        if self._closed:
            return self.path
        self._closed = True
        try:
            try:
                self._writer.close()  # ffmpeg finishes the file: a full disk fails here
            except Exception as exc:
                raise InputError(f"{self.path}: cannot write the video ({str(exc).splitlines()[0][:200]})") from None
            finally:
                self._renderer.close()
            if self.frames == 0:
                raise InputError(f"{self.path}: no frame was captured")
            commit_temp(self._tmp, self.path, "--video")
        except BaseException:
            self._tmp.unlink(missing_ok=True)
            raise
        return self.path

    def discard(self) -> None:
        """Stop without writing the file."""
        if self._closed:
            return
        self._closed = True
        try:
            self._writer.close()
        finally:
            self._renderer.close()
            self._tmp.unlink(missing_ok=True)

    def __enter__(self) -> VideoRecorder:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.discard()
