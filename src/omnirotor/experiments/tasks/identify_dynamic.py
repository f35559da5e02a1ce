"""Task ``identify-dynamic``: a free flight that excites the attitude, for the torque rows (issue 15, item 1).

The vehicle holds its position and, at a base attitude in each of the protocol's regions (upright in R1, and
the centres of R3 and R4's sampling boxes, SPEC §3.4), turns about each body axis in turn: rest-to-rest
minimum-jerk swings between ``±amplitude_deg`` whose durations shrink from ``slowest_s`` to ``fastest_s``
(a stepped sweep: slow swings excite the inputs near hover, fast ones large moments). The swings stay well
inside the region (10° about a base attitude 30° or more from the region's border) and within the rotor
limits. The controller flies the nominal map by default, as the authors' identification flights did (``--map``
chooses another).

Task ``identify-dynamic-cells`` flies the same excitation at the base of every flown cell of the
``torque-cells`` partition (:data:`CELL_BASES`: the R1 cap upright, four bases at 67.5° elevation around it,
three at 45° in each of R3 and R4; 11 bases, about 4 minutes of flight) and labels each sample with the cell
of its attitude, so that each cell gets its own torque rows and ``--blend smooth`` interpolates them
(issue 15; ``docs/beyond-the-paper.md`` §3). The ring swings reach 7.5° across their cells' borders; those
samples serve the neighbouring cell. This flight also adds a known input along the nominal map's null space
(:class:`NullSpaceDither`, :data:`CELL_NULL_DITHER_HZ2`): a controller flying the identified maps allocates
there, and a flight that never went there cannot tell the fit what the truth does there.

What a real robot logs is recorded: the gyroscope and the measured rotor speeds of every sensor frame
(the simulator's noise, bias and ESC noise included), and the region of the attitude, into
``flight.csv`` (:mod:`omnirotor.torque_identification` format) in the out folder. The flight needs Python
every period to copy the frame, so it runs the step-by-step loop (about five times slower than compiled).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from omnirotor.control.admittance import AdmittanceParams
from omnirotor.control.controller import InteractionController
from omnirotor.control.maps import MapParams
from omnirotor.control.trajectory import PoseTrajectory, capacity_for
from omnirotor.errors import InputError
from omnirotor.experiments.faults import plant_simulator
from omnirotor.experiments.loop import TaskOptions, run_closed_loop, run_log
from omnirotor.experiments.tasks.common import ExperimentOptions, ExperimentResult, base_metrics
from omnirotor.experiments.tasks.scenarios import body_to_ee_waypoint
from omnirotor.messages import RotorCommand, SensorFrame
from omnirotor.regions import load_partition
from omnirotor.sim import default_start_pose, scene_anchors
from omnirotor.so3 import exp_so3
from omnirotor.torque_identification import FlightLog, write_flight_csv
from omnirotor.vehicle import VehicleParams, load_vehicle

__all__ = [
    "SweepProtocol",
    "sweep_waypoints",
    "BASE_ATTITUDES",
    "CELL_BASES",
    "CELL_PARTITION",
    "CELL_NULL_DITHER_HZ2",
    "NullSpaceDither",
]

BASE_ATTITUDES = {"R1": (0.0, 90.0), "R3": (-90.0, 45.0), "R4": (90.0, 45.0)}
"""Base up direction (azimuth, elevation) [deg] per region: R1 upright, R3/R4 their sampling boxes' centres."""
CELL_PARTITION = "torque-cells"
"""The partition (preset) whose cells ``identify-dynamic-cells`` flies and labels its samples with."""
CELL_BASES = {
    "R1": {
        "R1.c": (0.0, 90.0),
        "R1.1": (-135.0, 67.5),
        "R1.2": (-45.0, 67.5),
        "R1.3": (45.0, 67.5),
        "R1.4": (135.0, 67.5),
    },
    "R3": {"R3.1": (-120.0, 45.0), "R3.2": (-90.0, 45.0), "R3.3": (-60.0, 45.0)},
    "R4": {"R4.1": (60.0, 45.0), "R4.2": (90.0, 45.0), "R4.3": (120.0, 45.0)},
}
"""Base up direction (azimuth, elevation) [deg] of each flown cell of :data:`CELL_PARTITION`, per paper region:
the centre of the cell (the R1 cap's: upright), where its smooth-blend weight is 1."""


CELL_NULL_DITHER_HZ2 = 6000.0
"""Null-space dither of the cells' flight [Hz²] (:class:`NullSpaceDither`): a controller flying the cells' maps
allocated up to about 7 600 Hz² into the nominal map's null space in hover (measured on the hover-only maps of
``study torque-rows``)."""


@dataclasses.dataclass(frozen=True)
class SweepProtocol:
    """The excitation of ``identify-dynamic``.

    Attributes:
        regions: regions visited (base attitudes in :data:`BASE_ATTITUDES`).
        amplitude_deg: swing amplitude about each axis [deg].
        slowest_s: duration of the first (slowest) swing [s].
        fastest_s: duration of the last (fastest) swing [s].
        swings: swings per axis.
        transition_s: time to turn to a region's base attitude [s].
        settle_s: hold before and after each axis's sweep [s].
        layout: "regions": one base per region (:data:`BASE_ATTITUDES`), samples labelled with the paper's
            regions; "cells": one base per flown cell of those regions (:data:`CELL_BASES`), samples labelled
            with the cells of :data:`CELL_PARTITION`.
        null_dither_hz2: amplitude of the input added along the null space of the nominal map [Hz²] per
            null-space coordinate (0: none; :class:`NullSpaceDither`).
    """

    regions: tuple[str, ...] = ("R1", "R3", "R4")
    amplitude_deg: float = 10.0
    slowest_s: float = 1.2
    fastest_s: float = 0.35
    swings: int = 8
    transition_s: float = 3.0
    settle_s: float = 0.5
    layout: str = "regions"
    null_dither_hz2: float = 0.0

    def __post_init__(self) -> None:
        unknown = [r for r in self.regions if r not in BASE_ATTITUDES]
        if unknown or not self.regions:
            raise InputError(f"identify-dynamic regions must be among {', '.join(BASE_ATTITUDES)}, got {self.regions}")
        if self.layout not in ("regions", "cells"):
            raise InputError(f"identify-dynamic layout must be regions or cells, got {self.layout!r}")
        if not (math.isfinite(self.null_dither_hz2) and 0.0 <= self.null_dither_hz2 <= 20000.0):
            raise InputError(f"null_dither_hz2 must be in [0, 20000] Hz², got {self.null_dither_hz2}")
        if not (0 < self.amplitude_deg <= 20):
            raise InputError(f"amplitude_deg must be in (0, 20], got {self.amplitude_deg}")
        if not (0 < self.fastest_s <= self.slowest_s) or self.swings < 2:
            raise InputError("need 0 < fastest_s <= slowest_s and swings >= 2")

    @staticmethod
    def quick(layout: str = "regions") -> SweepProtocol:
        """A shortened excitation (one region, fewer swings) for tests and ``--quick``."""
        return dataclasses.replace(
            SweepProtocol.for_layout(layout), regions=("R1",), swings=5, slowest_s=0.8, transition_s=1.0, settle_s=0.3
        )

    @staticmethod
    def for_layout(layout: str) -> SweepProtocol:
        """The full excitation of a layout: the cells' flight adds the null-space dither."""
        return SweepProtocol(layout=layout, null_dither_hz2=CELL_NULL_DITHER_HZ2 if layout == "cells" else 0.0)

    def bases(self) -> list[tuple[float, float]]:
        """The base up directions (azimuth, elevation) [deg] flown, in order."""
        if self.layout == "regions":
            return [BASE_ATTITUDES[r] for r in self.regions]
        return [b for r in self.regions for b in CELL_BASES[r].values()]


def base_attitude(az_el_deg: tuple[float, float]) -> np.ndarray:
    """An attitude R_WB whose up direction has this (azimuth, elevation) [deg], turned from upright about e3 x v."""
    az, el = (math.radians(a) for a in az_el_deg)
    v = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    # R_WB with third row v (R_WBᵀ e3 = v): turn e3 onto v about the axis e3 x v
    axis = np.cross([0.0, 0.0, 1.0], v)
    s = np.linalg.norm(axis)
    R_BW = np.eye(3) if s < 1e-12 else exp_so3(axis / s * math.atan2(s, v[2]))  # maps e3 to v
    return R_BW.T


def sweep_waypoints(p_body_W: np.ndarray, vehicle: VehicleParams, proto: SweepProtocol) -> tuple[list, float]:
    """EE waypoints of the excitation and its duration [s] (module docstring)."""
    t = 1.0
    up = np.eye(3)
    wps = [body_to_ee_waypoint(0.0, p_body_W, up, vehicle), body_to_ee_waypoint(t, p_body_W, up, vehicle)]
    amp = math.radians(proto.amplitude_deg)
    durations = np.geomspace(proto.slowest_s, proto.fastest_s, proto.swings)
    R0 = up
    for base in proto.bases():
        R0 = base_attitude(base)
        t += proto.transition_s
        wps.append(body_to_ee_waypoint(t, p_body_W, R0, vehicle))
        for axis in np.eye(3):
            t += proto.settle_s
            wps.append(body_to_ee_waypoint(t, p_body_W, R0, vehicle))
            for k, d in enumerate(durations):
                sign = 1.0 if k % 2 == 0 else -1.0
                amp_k = amp if k > 0 else 0.5 * amp  # the first swing starts from the base: half way
                t += float(d)
                wps.append(body_to_ee_waypoint(t, p_body_W, R0 @ exp_so3(sign * amp_k * axis), vehicle))
            t += float(durations[-1])
            wps.append(body_to_ee_waypoint(t, p_body_W, R0, vehicle))
    t += proto.settle_s
    wps.append(body_to_ee_waypoint(t, p_body_W, R0, vehicle))
    return wps, t + 0.5


class NullSpaceDither:
    """The simulator, with a known input added to every rotor command along the nominal map's null space.

    A controller that allocates with (nearly) the pseudo-inverse of the nominal map puts its inputs in that
    map's row space only, so a flight leaves the torque rows on the null space undetermined. A controller
    flying the *identified* maps allocates into that null space (by 8-14 % of the input norm in hover on the
    Omnirotor), where the truth's moments differ from the fitted rows' (issue 15). The identification flight
    therefore adds ``u_d(t) = N z(t)`` to the allocated inputs ``u = sign(w) w²`` [Hz²], ``N`` (n, n - 6) an
    orthonormal basis of the nominal map's null space and each coordinate of ``z`` a sum of four sines of
    0.23-1.9 Hz with seeded phases scaled to peak ``amplitude_hz2``; the nominal map says it makes no wrench,
    the truth makes a small one that the controller rejects. Commands stay within the rotor limits. The
    measured rotor speeds carry it into the flight log, so the fit sees it like any other input.

    Args:
        sim: the simulator (every attribute but ``step`` is the simulator's).
        vehicle: the vehicle (nominal map, rotor limit).
        amplitude_hz2: peak of each null-space coordinate [Hz²].
        seed: seed of the sines' phases.
    """

    _FREQS_HZ = (0.23, 0.51, 0.97, 1.9)

    def __init__(self, sim, vehicle: VehicleParams, amplitude_hz2: float, seed: int) -> None:
        self._sim = sim
        self._null = np.linalg.svd(vehicle.A_nom)[2][6:].T.copy()
        k = self._null.shape[1]
        self._phase = np.random.default_rng([seed, 15]).uniform(0.0, 2.0 * math.pi, (k, len(self._FREQS_HZ)))
        self._freq = 2.0 * math.pi * np.asarray(self._FREQS_HZ)
        self._scale = amplitude_hz2 / len(self._FREQS_HZ)
        self._w_lo, self._w_hi = vehicle.omega_min_hz, vehicle.omega_max_hz

    def __getattr__(self, name: str):
        return getattr(self._sim, name)

    def dither_hz2(self, t: float) -> np.ndarray:
        """(n,) the input added at time ``t`` [s] [Hz²]."""
        z = self._scale * np.sin(self._freq[None, :] * t + self._phase).sum(axis=1)
        return self._null @ z

    def step(self, cmd: RotorCommand) -> SensorFrame:
        """The simulator's step under ``cmd`` plus the dither."""
        w = cmd.omega_hz
        u = np.sign(w) * w * w + self.dither_hz2(self._sim.t)
        w_new = np.clip(np.sign(u) * np.sqrt(np.abs(u)), self._w_lo, self._w_hi)
        return self._sim.step(RotorCommand(cmd.t, w_new, cmd.status))


class _FrameTap:
    """Copies the gyro and the measured rotor speeds of every sensor frame (``on_step`` of the loop)."""

    def __init__(self, n_steps: int, n_rotors: int) -> None:
        self.gyro = np.zeros((n_steps + 1, 3))
        self.rotor = np.zeros((n_steps + 1, n_rotors))
        self.t = np.zeros(n_steps + 1)
        self.k = 0
        self.n = n_rotors

    def __call__(self, sim, t: float) -> None:
        if self.k == 0:  # the reset frame was consumed by the controller; the first step's frame follows
            self.k = 1
            return
        b = sim.frame_record
        i = self.k - 1
        if i < self.t.size:
            self.t[i] = b["t"][0]
            self.gyro[i] = b["imu"]["gyro_B"][0]
            self.rotor[i] = b["rotor_hz"][0]
        self.k += 1


def identify_dynamic(options: TaskOptions, progress=None) -> ExperimentResult:
    """Fly the attitude excitation and write ``flight.csv`` into the out folder (module docstring)."""
    return fly_sweeps(options, None, progress)


def identify_dynamic_cells(options: TaskOptions, progress=None) -> ExperimentResult:
    """The same excitation at the base of every flown cell (:data:`CELL_BASES`); samples labelled by cell."""
    return fly_sweeps(options, None, progress, "cells")


def fly_sweeps(
    options: TaskOptions, proto: SweepProtocol | None, progress=None, layout: str = "regions"
) -> ExperimentResult:
    """Fly an excitation and write ``flight.csv`` into the out folder (the tasks ``identify-dynamic[-cells]``).

    Args:
        options: the run's options.
        proto: the excitation; None: the layout's, quick or full (:meth:`SweepProtocol.for_layout`).
        progress: progress callback of the loop.
        layout: "regions" or "cells", when ``proto`` is None.
    """
    if proto is not None:
        layout = proto.layout
    if isinstance(options, ExperimentOptions):
        opts = options
    else:
        opts = ExperimentOptions(**{f.name: getattr(options, f.name) for f in dataclasses.fields(TaskOptions)})
    vehicle = load_vehicle(opts.vehicle)
    if proto is None:
        proto = SweepProtocol.quick(layout) if opts.quick else SweepProtocol.for_layout(layout)
    scene = opts.sim_params().scene
    p_body, _ = default_start_pose(scene_anchors("free", scene), vehicle, scene)
    wps, duration = sweep_waypoints(p_body, vehicle, proto)
    if opts.duration_s is not None:
        duration = opts.duration_s
    params = opts.controller_params(AdmittanceParams.preset("free"))
    waypoints = max(params.trajectory_waypoints, capacity_for(len(wps)))  # room for the sweep's trajectory
    params = dataclasses.replace(
        params, maps=MapParams(mode=opts.map_mode, blend=opts.blend), trajectory_waypoints=waypoints
    )
    controller = InteractionController(vehicle, params, opts.load_maps(vehicle))
    sim = plant_simulator(vehicle, "free", opts.sim_params(), opts.seed, opts.plant, controller)
    if proto.null_dither_hz2 > 0:
        sim = NullSpaceDither(sim, vehicle, proto.null_dither_hz2, opts.seed)
    n_steps = int(round(duration / controller.params.dt))
    tap = _FrameTap(n_steps, vehicle.n_rotors)
    ctl_log, truth_log = run_closed_loop(sim, controller, PoseTrajectory(wps), duration, progress, on_step=tap)
    log = run_log(ctl_log, truth_log)
    # the frame read before step k+1 is the one step k produced: row k of the logs
    n = min(tap.k - 1, log.t.size)
    partition = load_partition("paper" if layout == "regions" else CELL_PARTITION)
    R_true = truth_log.group("R_WB")[:n].reshape(-1, 3, 3)
    region = tuple(partition.name_of_attitude(R) for R in R_true)
    flight = FlightLog(tap.t[:n].copy(), tap.gyro[:n].copy(), tap.rotor[:n].copy(), region)
    tilt = np.degrees(np.arccos(np.clip(R_true[:, 2, 2], -1, 1)))
    task = "identify-dynamic" if layout == "regions" else "identify-dynamic-cells"
    m = base_metrics(task, opts, log, duration, truth_log.group("controller_step_us"), vehicle)
    m["samples"] = int(n)
    flown = proto.regions if layout == "regions" else [c for r in proto.regions for c in CELL_BASES[r]]
    m["samples_per_region"] = {r: region.count(r) for r in flown}
    m["omega_B_max_rad_s"] = float(np.abs(flight.gyro_B).max())
    m["tilt_max_deg"] = float(tilt.max())
    m["rotor_speed_min_abs_hz"] = float(np.abs(flight.rotor_hz).min())
    m["success"] = bool(m["steps_flagged"] == 0)
    if opts.out_dir is not None:
        path = Path(opts.out_dir) / "flight.csv"
        write_flight_csv(path, flight)
        m["flight_csv"] = str(path)
    return ExperimentResult(
        task=task,
        options=opts,
        duration_s=duration,
        controller_log=ctl_log,
        truth_log=truth_log,
        metrics=m,
        log=log,
    )
