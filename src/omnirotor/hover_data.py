"""Hover points: the data of a piecewise wrench-map identification (SPEC §3.1).

Its own module, imported by :mod:`omnirotor.identification` (which re-exports :class:`HoverData`) and by the
readers that produce hover points (:mod:`omnirotor.px4.windows`), so that neither imports the other's module.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from omnirotor.errors import InputError

__all__ = ["HoverData"]


@dataclasses.dataclass(frozen=True)
class HoverData:
    """Hover points: rotor inputs and the body wrench that held the vehicle.

    Attributes:
        u_hz2: (N, n) rotor inputs ``sign(ω) ω²`` [Hz²].
        w_B: (N, 6) body wrench at the CoM [N, N·m].
        region: (N,) region name of each point ("" = derive from the force direction).
        source: (N,) file each point came from.
    """

    u_hz2: np.ndarray
    w_B: np.ndarray
    region: tuple[str, ...]
    source: tuple[str, ...]

    def __post_init__(self) -> None:
        if self.u_hz2.ndim != 2 or self.w_B.shape != (self.u_hz2.shape[0], 6):
            raise InputError(f"hover data: shapes {self.u_hz2.shape} and {self.w_B.shape} do not match")
        if not (np.all(np.isfinite(self.u_hz2)) and np.all(np.isfinite(self.w_B))):
            raise InputError("hover data contain NaN or inf")

    @property
    def n_points(self) -> int:
        """Number of hover points."""
        return int(self.u_hz2.shape[0])

    def subset(self, mask: np.ndarray) -> HoverData:
        """The points selected by a boolean mask."""
        idx = np.flatnonzero(mask)
        return HoverData(
            self.u_hz2[idx],
            self.w_B[idx],
            tuple(self.region[i] for i in idx),
            tuple(self.source[i] for i in idx),
        )

    @staticmethod
    def concatenate(parts: Sequence[HoverData]) -> HoverData:
        """Join several data sets with the same number of rotors."""
        widths = {p.u_hz2.shape[1] for p in parts}
        if len(widths) > 1:
            raise InputError(f"hover data files disagree on the number of rotors: {sorted(widths)}")
        return HoverData(
            np.vstack([p.u_hz2 for p in parts]),
            np.vstack([p.w_B for p in parts]),
            tuple(r for p in parts for r in p.region),
            tuple(s for p in parts for s in p.source),
        )
