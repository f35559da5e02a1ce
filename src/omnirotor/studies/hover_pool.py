"""Hover points of the simulator's truth aerodynamics, with measurement noise, for identification studies (SPEC §3).

A *pool* holds, per region of a partition, random attitudes (the protocol's sampler
:func:`~omnirotor.experiments.tasks.scenarios.hover_attitudes`, which rejects attitudes whose nominal hover needs a
rotor slower than ``min_speed_hz``) and the true steady hover inputs there: the inputs of a controller
flying the nominal map with integral action, under the truth model
(:func:`~omnirotor.sim.aero.hover_equilibrium` with ``make_aero(vehicle)``, the calibrated rotor-wake
model by default). Attitudes the truth cannot hold are skipped, as a pilot would skip them.

A draw takes points from the pool and adds the measurement noise of a hold average
(:class:`HoverNoise`): white noise on each mean rotor speed [Hz] and a small random rotation of the
attitude estimate [deg]; the "measured" wrench is the hover wrench ``[R_measᵀ m g e3; 0]`` (SPEC §3.1).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from omnirotor.errors import InputError
from omnirotor.experiments.tasks.scenarios import hover_attitudes
from omnirotor.identification import HoverData
from omnirotor.regions import Partition
from omnirotor.sim.aero import TruthAero, hover_equilibrium
from omnirotor.so3 import exp_so3
from omnirotor.vehicle import VehicleParams

__all__ = ["HoverNoise", "HoverPool", "build_pool", "draw", "NOISE_LEVELS"]


@dataclasses.dataclass(frozen=True)
class HoverNoise:
    """Measurement noise of one hover point (a hold average).

    Attributes:
        speed_std_hz: standard deviation of each mean rotor speed [Hz].
        attitude_std_deg: standard deviation of each axis of the attitude error [deg].
    """

    speed_std_hz: float = 1.0
    attitude_std_deg: float = 0.5

    def __post_init__(self) -> None:
        for name in ("speed_std_hz", "attitude_std_deg"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise InputError(f"{name} must be a finite number >= 0, got {v}")


NOISE_LEVELS = {
    "low": HoverNoise(0.2, 0.1),
    "medium": HoverNoise(1.0, 0.5),
    "high": HoverNoise(3.0, 1.5),
}
"""Named noise levels of the studies [A]: ``medium`` is a 5 s hold of ESC telemetry and motion capture."""


@dataclasses.dataclass(frozen=True)
class HoverPool:
    """Truth hover points per region.

    Attributes:
        R_WB: region name -> (k, 3, 3) attitudes.
        u_hz2: region name -> (k, n) true steady inputs [Hz²].
    """

    R_WB: dict[str, np.ndarray]
    u_hz2: dict[str, np.ndarray]

    def size(self, region: str) -> int:
        """Points of a region in the pool."""
        return int(self.u_hz2[region].shape[0])


def build_pool(
    vehicle: VehicleParams,
    aero: TruthAero,
    partition: Partition,
    per_region: int,
    rng: np.random.Generator,
    min_speed_hz: float = 50.0,
    A_map: np.ndarray | None = None,
) -> HoverPool:
    """Sample ``per_region`` held attitudes in every region of ``partition`` and their true hover inputs.

    Args:
        vehicle: the vehicle.
        aero: the truth model.
        partition: the regions.
        per_region: attitudes per region.
        rng: random generator.
        min_speed_hz: the protocol's rejection of attitudes near a rotor's zero crossing [Hz].
        A_map: the map the hovering controller allocates with (default: nominal).

    Returns:
        The pool (a region may hold fewer points if the truth cannot hold some attitudes).
    """
    Rs: dict[str, np.ndarray] = {}
    us: dict[str, np.ndarray] = {}
    for name in partition.names:
        R_list, u_list = [], []
        for _, R in hover_attitudes(partition, [name], per_region, rng, vehicle, min_speed_hz):
            try:
                u_list.append(hover_equilibrium(aero, vehicle, R, A_map))
            except InputError:
                continue
            R_list.append(R)
        n = vehicle.n_rotors
        Rs[name] = np.array(R_list).reshape(-1, 3, 3)
        us[name] = np.array(u_list).reshape(-1, n)
    return HoverPool(Rs, us)


def draw(
    pool: HoverPool,
    vehicle: VehicleParams,
    counts: dict[str, int],
    noise: HoverNoise,
    rng: np.random.Generator,
    label: bool = True,
) -> HoverData:
    """Noisy hover data: ``counts[name]`` points of each region drawn from the pool without replacement.

    Args:
        pool: the truth points.
        vehicle: the vehicle (weight).
        counts: points per region.
        noise: the measurement noise.
        rng: random generator.
        label: label each point with its region (as a protocol that knows where it flew); False: the
            identification derives it from the measured force direction.

    Returns:
        The hover data.
    """
    u_rows, w_rows, names = [], [], []
    up = np.array([0.0, 0.0, vehicle.weight])
    for name, k in counts.items():
        if k > pool.size(name):
            raise InputError(f"region {name}: {k} points asked, the pool holds {pool.size(name)}")
        for j in rng.choice(pool.size(name), size=k, replace=False):
            u = pool.u_hz2[name][j]
            omega = np.sign(u) * np.sqrt(np.abs(u)) + noise.speed_std_hz * rng.standard_normal(u.size)
            R = pool.R_WB[name][j] @ exp_so3(np.radians(noise.attitude_std_deg) * rng.standard_normal(3))
            u_rows.append(np.sign(omega) * omega**2)
            w_rows.append(np.concatenate([R.T @ up, np.zeros(3)]))
            names.append(name if label else "")
    N = len(u_rows)
    return HoverData(np.array(u_rows), np.array(w_rows), tuple(names), ("truth",) * N)
