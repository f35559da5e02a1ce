"""The quadrotor hover in crazyflow (https://github.com/learnsyslab/crazyflow), timed; prints one JSON object.

Run by ``benchmarks/run.py`` in a subprocess with the interpreter of the venv that holds crazyflow (``make bench``
creates ``out/peer-venvs/crazyflow`` from ``benchmarks/peer-crazyflow.txt``), so that JAX and its XLA threads
neither enter nor disturb the process that times omnirotor. This file imports nothing from omnirotor.

The task is the shared hover of ``peer_rotorpy.py``: one Crazyflie holding (0, 0, 1.5) m, the dynamics at
1 kHz. crazyflow is used as its documentation does: ``Sim(n_worlds, control=Control.state, freq=1000)`` with
its defaults otherwise (first-principles dynamics of the cf21B_500, explicit Euler, float32, the state
controller at 100 Hz and the attitude controller at 500 Hz inside the compiled step), the target set with
``sim.state_control(cmd)``. Three ways of stepping it, each timed after an untimed call of the same shape
(JAX compiles per shape on first call) that also settles the hover from the drone's start state:

* ``scan``: the whole horizon as one compiled call, ``sim.step(n)``;
* ``python_100hz``: Python sets the target at 100 Hz and steps ``sim.freq // sim.control_freq`` periods per
  call, as the README's example loop does;
* ``batched``: the README loop with ``n_worlds`` independent worlds (drone-seconds per wall second).

Usage: ``python peer_crazyflow.py --duration 5 --repeats 3 --worlds 1000 10000``.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
from importlib.metadata import version

FREQ_HZ = 1000
"""Dynamics step rate [Hz] (the shared task's 1 kHz)."""
HOVER_POS_M = (0.0, 0.0, 1.5)
SETTLE_S = 1.0
"""Simulated seconds of the untimed first call (compilation and settling into the hover)."""


def _make(n_worlds: int):
    import numpy as np
    from crazyflow.control import Control
    from crazyflow.sim import Sim

    sim = Sim(n_worlds=n_worlds, n_drones=1, control=Control.state, freq=FREQ_HZ)
    cmd = np.zeros((n_worlds, 1, 16), dtype=np.float32)
    cmd[..., 0:3] = HOVER_POS_M
    cmd[..., 12] = 1.0  # quaternion xyzw, identity
    states = sim.data.states
    pos = np.broadcast_to(np.asarray(HOVER_POS_M, dtype=np.float32), states.pos.shape)
    sim.data = sim.data.replace(states=states.replace(pos=sim.data.states.pos.at[...].set(pos)))
    sim.state_control(cmd)
    return sim, cmd


def _block(sim) -> None:
    import jax

    jax.block_until_ready(sim.data)


def _loop_100hz(sim, cmd, n_calls: int) -> None:
    k = sim.freq // sim.control_freq
    for _ in range(n_calls):
        sim.state_control(cmd)
        sim.step(k)


def _timed(fn) -> tuple[float, float]:
    tic, cpu0 = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - tic, time.process_time() - cpu0


class Runner:
    """One ``Sim`` of ``n_worlds`` worlds stepped one way (``scan`` or ``python_100hz``), compiled and settled.

    Each :meth:`timed` call starts again from the settled state and times ``duration_s`` simulated seconds.
    """

    def __init__(self, mode: str, n_worlds: int, duration_s: float):
        self.mode, self.n_worlds, self.duration_s = mode, n_worlds, duration_s
        self.sim, self.cmd = _make(n_worlds)
        self.walls: list[float] = []
        self.cpus: list[float] = []
        sim = self.sim
        k = sim.freq // sim.control_freq
        tic = time.perf_counter()
        if mode == "scan":
            self.n = int(round(duration_s * sim.freq))
            sim.step(int(round(SETTLE_S * sim.freq)))
            self.start = sim.data
            sim.step(self.n)  # compile the timed shape
        else:
            self.n = int(round(duration_s * sim.freq / k))
            _loop_100hz(sim, self.cmd, int(round(SETTLE_S * sim.freq / k)))
            self.start = sim.data
        _block(sim)
        self.first_call_wall_s = time.perf_counter() - tic

    def _go(self) -> None:
        if self.mode == "scan":
            self.sim.step(self.n)
        else:
            _loop_100hz(self.sim, self.cmd, self.n)
        _block(self.sim)

    def timed(self) -> None:
        """Time one run of ``duration_s`` from the settled state."""
        self.sim.data = self.start
        w, c = _timed(self._go)
        self.walls.append(w)
        self.cpus.append(c)

    def figures(self) -> dict:
        """Medians over the timed runs (see :func:`_figures`)."""
        return _figures(self.duration_s, self.n_worlds, self.walls, self.cpus, self.first_call_wall_s,
                        self.sim.data.states.pos)  # fmt: skip


def _figures(duration_s: float, n_worlds: int, walls: list[float], cpus: list[float], first: float, pos) -> dict:
    import numpy as np

    p = np.asarray(pos, dtype=float).reshape(-1, 3)
    err_mm = 1e3 * np.linalg.norm(p - np.asarray(HOVER_POS_M), axis=1)
    wall, cpu = statistics.median(walls), statistics.median(cpus)
    return {
        "n_worlds": n_worlds,
        "duration_s": duration_s,
        "repeats": len(walls),
        "wall_s_runs": walls,
        "wall_s": wall,
        "rtf": duration_s / wall,
        "rtf_cpu": duration_s / cpu,
        "drone_s_per_wall_s": n_worlds * duration_s / wall,
        "first_call_wall_s": first,
        "final_pos_err_mm_max": float(err_mm.max()),
        "dtype": str(np.asarray(pos).dtype),
    }


def main(argv: list[str] | None = None) -> int:
    """Command line (module docstring)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=5.0, help="simulated seconds per timed run")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--worlds", type=int, nargs="*", default=[1000], help="world counts of the batched runs")
    ap.add_argument("--batched-duration", type=float, default=None, help="simulated seconds of batched runs")
    args = ap.parse_args(argv)
    tic = time.perf_counter()
    import jax

    out: dict = {
        "version": version("crazyflow"),
        "jax": version("jax"),
        "python": platform.python_version(),
        "x64": bool(jax.config.jax_enable_x64),
        "freq_hz": FREQ_HZ,
        "import_s": time.perf_counter() - tic,
    }
    # the two single-world modes alternate run by run, as the rest of the benchmark does
    single = [Runner("scan", 1, args.duration), Runner("python_100hz", 1, args.duration)]
    for r in range(args.repeats):
        for runner in single if r % 2 == 0 else single[::-1]:
            runner.timed()
    out["scan"], out["python_100hz"] = (x.figures() for x in single)
    bd = args.batched_duration if args.batched_duration is not None else args.duration
    out["batched"] = []
    for n in args.worlds:
        runner = Runner("python_100hz", n, bd)
        for _ in range(args.repeats):
            runner.timed()
        out["batched"].append(runner.figures())
    out["wall_s"] = time.perf_counter() - tic
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
