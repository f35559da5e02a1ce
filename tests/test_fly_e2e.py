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


@pytest.mark.slow
def test_an_interactive_flight_takes_off_from_the_floor_lands_on_it_and_ends_on_sigterm(tmp_path, capsys):
    """``sim --serve`` (no task) + ``fly`` + ``ctl`` as a user flies them: arm, take off, goto, land, disarm.

    The vehicle waits on the scene's floor (not held in the air at the task start height, where a landing would
    disarm it in the air and drop it), and SIGTERM ends both processes with their summaries, exit 0.
    """
    import signal

    sim_ep, node_ep, ns = f"tcp/127.0.0.1:{free_port()}", f"tcp/127.0.0.1:{free_port()}", "/hand"
    sim_cmd = ["sim", "--serve", "--scene", "free", "--listen", sim_ep, "--namespace", ns, "--fifo-priority", "0"]
    node_cmd = ["fly", "--connect", sim_ep, "--listen", node_ep, "--namespace", ns, "--fifo-priority", "0"]
    errs = [open(tmp_path / f"{name}.err", "w+") for name in ("sim", "node")]  # noqa: SIM115
    procs = [subprocess.Popen([sys.executable, "-c", CLI, *cmd], stdout=subprocess.PIPE, stderr=err, env=env(),
                              text=True) for cmd, err in zip((sim_cmd, node_cmd), errs, strict=True)]  # fmt: skip
    base = ["ctl", "--connect", node_ep, "--namespace", ns, "--timeout", "2"]

    def ask(*args) -> tuple[int, str]:
        code = main([*base, *args])
        return code, capsys.readouterr().out

    def mode(name: str):
        return lambda: name in ask("status")[1] or None

    try:
        assert wait_until(lambda: ask("status")[0] == 0 or None, timeout_s=300.0, step_s=0.5), errs[1].name
        # a user retries a refused arm: on a loaded machine a frame 20 ms late makes the IMU stale for a moment
        code, out = wait_until(lambda: (r := ask("arm"))[0] == 0 and r, timeout_s=10.0, step_s=0.3) or ask("arm")
        assert code == 0 and out.startswith("accepted: arm: disarmed -> armed (ground at ("), out
        ground_z = float(out.split("ground at (")[1].split(")")[0].split(",")[2])
        assert ground_z < 0.5  # on the floor (the free scene's start pose is 1.5 m up)
        code, out = ask("takeoff", "--height", "0.8")
        assert code == 0, out
        assert wait_until(mode("mode hold"), timeout_s=60.0, step_s=0.5)
        code, out = ask("goto", "0.3", "0.2", "1.2")
        assert code == 0, out
        assert wait_until(mode("mode hold"), timeout_s=60.0, step_s=0.5)
        code, out = ask("land")
        assert code == 0 and "-> land" in out, out
        assert wait_until(mode("mode disarmed"), timeout_s=60.0, step_s=0.5)
        code, out = ask("status")
        assert "landed" in out, out
        code, out = wait_until(lambda: (r := ask("arm"))[0] == 0 and r, timeout_s=10.0, step_s=0.3) or ask("arm")
        assert code == 0, out  # landed on the floor again: it can arm there
        landed_z = float(out.split("ground at (")[1].split(")")[0].split(",")[2])
        assert abs(landed_z - ground_z) < 0.05
        for p in reversed(procs):
            p.send_signal(signal.SIGTERM)
        outs = [p.communicate(timeout=60)[0] for p in procs]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
    for err in errs:
        err.seek(0)
    text = [err.read() for err in errs]
    assert [p.returncode for p in procs] == [0, 0], text
    assert "steps flown" in outs[0] and "frames" in outs[1]
    plant = text[0].split("plant session ")[1].split()[0]  # the simulator's, said at its start
    assert f"plant session {plant} (first come); frames of other plant sessions refused: 0" in outs[1]
    assert "link lost" not in text[1], text[1]  # no frame gap at the release from the floor
    assert "Traceback" not in text[0] + text[1]
