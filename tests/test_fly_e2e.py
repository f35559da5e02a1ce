"""The three processes of the README's example: ``omnirotor sim --serve``, ``omnirotor fly`` and ``omnirotor ctl``.

The simulator serves the hover task (lockstep, and a long offboard-loss delay: a loaded machine must not stop the
run while the node loads its compiled kernels; the failsafes have their own tests),
the node flies it as a mission (its director tracking the task's trajectory), and ``ctl`` requests go over real
Zenoh on loopback to the node's director, between its periods, and come back.
"""

from __future__ import annotations

import subprocess
import sys

import pytest

from omnirotor.cli import main
from sitl.procs import CLI, env, free_port, wait_until

pytest.importorskip("zenoh")


@pytest.mark.slow
def test_ctl_talks_to_a_flying_node(tmp_path, capsys):
    sim_ep, node_ep, ns = f"tcp/127.0.0.1:{free_port()}", f"tcp/127.0.0.1:{free_port()}", "/e2e"
    sim_cmd = ["sim", "--serve", "--task", "hover", "--quick", "--lockstep", "--duration", "120",
               "--offboard-loss", "60", "--listen", sim_ep, "--namespace", ns, "--json",
               "--out", str(tmp_path / "sim")]  # fmt: skip
    node_cmd = ["fly", "--mission-from-sim", "--connect", sim_ep, "--listen", node_ep, "--namespace", ns, "--json",
                "--fifo-priority", "0"]  # fmt: skip
    errs = [open(tmp_path / f"{name}.err", "w") for name in ("sim", "node")]  # noqa: SIM115
    procs = [subprocess.Popen([sys.executable, "-c", CLI, *cmd], stdout=subprocess.DEVNULL, stderr=err, env=env())
             for cmd, err in zip((sim_cmd, node_cmd), errs, strict=True)]  # fmt: skip
    base = ["ctl", "--connect", node_ep, "--namespace", ns, "--timeout", "1"]
    try:

        def answered():
            code = main([*base, "status"])
            out = capsys.readouterr().out
            return out if code == 0 and "mode hold" in out else None

        # The hover mission's trajectory is one pose: the director tracks it, then holds it.
        out = wait_until(answered, timeout_s=300.0, step_s=0.5)  # start-up (numba's cache, Zenoh) on a loaded machine
        assert out is not None, (tmp_path / "node.err").read_text()[-2000:]
        assert out.startswith("accepted: status: mode hold, preset task, map nominal")
        assert main([*base, "takeoff"]) == 1
        assert capsys.readouterr().out == "refused: takeoff: already flying (mode hold)\n"
        assert main([*base, "push", "0.05"]) == 0
        out = capsys.readouterr().out
        assert out.startswith("accepted: push: hold -> contact (depth 0.050 m") and "preset PC: about 1.5 N" in out
        assert main([*base, "status"]) == 0
        assert capsys.readouterr().out.startswith(
            "accepted: status: mode contact, preset PC, map nominal, depth 0.050 m"
        )
        assert main([*base, "disarm", "--force"]) == 0
        assert "rotors stopped in flight (forced)" in capsys.readouterr().out
        assert main([*base, "status"]) == 0
        assert capsys.readouterr().out.startswith("accepted: status: mode disarmed")
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait(timeout=10)
        for f in errs:
            f.close()
