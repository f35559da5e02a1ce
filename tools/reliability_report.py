"""Bad-input probes of every command and file format, and the table of docs/reliability.md (issue 14).

Each probe builds its inputs in a fresh folder, runs one ``omnirotor`` command in this process (stdout and
stderr captured at the file-descriptor level, so MuJoCo's C output counts too) and classifies the outcome:

* ``one line, exit 2`` — what the project promises for bad input: exit status 2, exactly one line on stderr
  (``omnirotor: error: ...``), nothing on stdout, and no file created, changed or removed in the folder;
* ``note, exit 0`` — a probe that is accepted on purpose, with the value changed or assumed said on stderr;
* anything else is a failure and named (traceback, exit 0, noise on stderr, files written, hung).

It also flies every single-frame sensor glitch of ``omnirotor.experiments.faults.FRAME_GLITCHES`` into a hover
and reports what the controller's frame supervision made of it (:func:`run_glitches`).

It flies the closed-loop check of the estimator's motion-capture noise matching (:func:`run_noise_matching`:
hovers on a motion capture noisier, or less noisy, than the estimator is told).

``python tools/reliability_report.py`` runs the probes and the hovers and rewrites ``docs/reliability.md``;
``--check`` exits 1 if the file is not current (the hovers' figures re-read from it, as measuring them takes
minutes); ``--keep-noise`` rewrites it with the hovers' figures it has. ``tests/test_reliability_report.py``
does the same.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import signal
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "reliability.md"
LONG = "n" * 300
"""A file name longer than the 255 bytes Linux allows."""
HUGE_INT = "9" * 400
"""An integer too big for a float."""
PROBE_TIMEOUT_S = 60


@dataclasses.dataclass(frozen=True)
class Probe:
    """One bad input: its group, a description, the command line (``{t}`` = its folder) and its files."""

    group: str
    what: str
    argv: tuple[str, ...]
    setup: Callable[[Path], None] | None = None
    expect: str = "exit2"  # or "note": accepted with a note on stderr


def _preset(kind: str, name: str) -> str:
    from importlib.resources import files

    return (files("omnirotor") / "presets" / kind / f"{name}.toml").read_text()


def _vehicle(text_from: str, text_to: str) -> Callable[[Path], None]:
    def setup(t: Path) -> None:
        src = _preset("vehicles", "omnirotor")
        assert text_from in src, text_from
        (t / "v.toml").write_text(src.replace(text_from, text_to, 1))

    return setup


def _write(name: str, content: str | bytes) -> Callable[[Path], None]:
    def setup(t: Path) -> None:
        p = t / name
        p.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(content, bytes):
            p.write_bytes(content)
        else:
            p.write_text(content)

    return setup


def _maps_dict() -> dict:
    from omnirotor.regions import load_partition
    from omnirotor.vehicle import load_vehicle
    from omnirotor.wrench_maps import MapEntry, WrenchMapSet

    A = load_vehicle().A_nom
    maps = WrenchMapSet(
        vehicle="omnirotor",
        nominal=A,
        partition=load_partition(),
        regions={"R1": MapEntry(A * 1.05, 8, 0.01, 2.0, True)},
        global_=MapEntry(A * 1.02, 16, 0.1, 2.0, True),
        delta=3e-5,
        weights=(10.0, 10.0, 10.0, 1e-12, 1e-12, 1e-12),
        rho=1e-8,
    )
    return json.loads(json.dumps(maps.to_dict()))


def _maps(edit: Callable[[dict], object] | None = None, raw: Callable[[str], str] | None = None, name="m.json"):
    def setup(t: Path) -> None:
        d = _maps_dict()
        if edit is not None:
            edit(d)
        text = json.dumps(d)
        if raw is not None:
            text = raw(text)
        (t / name).write_text(text)

    return setup


def _good_maps(t: Path) -> None:
    _maps()(t)


def _csv(speed_scale: float = 1.0, cell: str | None = None, name: str = "h.csv") -> Callable[[Path], None]:
    def setup(t: Path) -> None:
        import numpy as np

        from omnirotor.identification import write_csv
        from omnirotor.so3 import rot_x, rot_y
        from omnirotor.vehicle import load_vehicle

        v = load_vehicle()
        rng = np.random.default_rng(0)
        Rs = [rot_x(a) @ rot_y(b) for a, b in rng.uniform(-0.3, 0.3, size=(12, 2))]
        u = np.array([v.hover_input(R) for R in Rs])
        omega = np.sign(u) * np.sqrt(np.abs(u)) * speed_scale
        write_csv(t / name, Rs, omega, ["R1"] * len(Rs))
        if cell is not None:
            lines = (t / name).read_text().splitlines()
            fields = lines[1].split(",")
            fields[5] = cell
            lines[1] = ",".join(fields)
            (t / name).write_text("\n".join(lines) + "\n")

    return setup


def _mat(off_diagonal: float = 0.0, speed_scale: float = 1.0) -> Callable[[Path], None]:
    def setup(t: Path) -> None:
        import numpy as np
        import scipy.io as sio

        from omnirotor.so3 import rot_x
        from omnirotor.vehicle import load_vehicle

        v = load_vehicle()
        u = np.array([v.hover_input(rot_x(a)) for a in (0.0, 0.1, 0.2, -0.1, -0.2, 0.05)]) * speed_scale**2
        U = np.vstack([np.kron(row[None, :], np.eye(6)) for row in u])
        U[0, 1] = off_diagonal * u[0, 0]  # an off-diagonal entry of the first block
        Z = np.tile([0.0, 0.0, v.weight, 0.0, 0.0, 0.0], u.shape[0])
        sio.savemat(t / "h.mat", {"wMapStruct": {"U": U, "Z": Z}})

    return setup


def _fifo(name: str) -> Callable[[Path], None]:
    return lambda t: os.mkfifo(t / name)


def _symlink(name: str, target: str) -> Callable[[Path], None]:
    def setup(t: Path) -> None:
        (t / target).write_text("keep me\n")
        (t / name).symlink_to(t / target)

    return setup


def _dir(name: str) -> Callable[[Path], None]:
    return lambda t: (t / name).mkdir()


def _both(*fns: Callable[[Path], None]) -> Callable[[Path], None]:
    def setup(t: Path) -> None:
        for f in fns:
            f(t)

    return setup


def _campaign_folder(results: str, definition: str | None = None) -> Callable[[Path], None]:
    def setup(t: Path) -> None:
        (t / "c").mkdir()
        (t / "c" / "results.jsonl").write_text(results)
        if definition is not None:
            (t / "c" / "campaign.json").write_text(definition)

    return setup


_DEFINITION = json.dumps(
    {"hash": "0" * 64, "definition": {"task": "sliding", "vary": {"gamma": {}}, "options": {"map": "nominal"}}}
)
_ONE_RUN = json.dumps({"index": 0, "status": "ok", "params": {"gamma": 4.0}, "success": True, "metrics": {}}) + "\n"


def _ulog(edit: Callable[[bytes], bytes] | None = None, name: str = "f.ulg", rotor_count: float = 4):
    """The project's synthetic hover log (``write_hover_log``), its bytes edited."""

    def setup(t: Path) -> None:
        from omnirotor.px4.ulog_writer import write_hover_log

        write_hover_log(t / name, rotor_count)
        if edit is not None:
            (t / name).write_bytes(edit((t / name).read_bytes()))

    return setup


def _fmt(topic: str, old: str, new: str) -> Callable[[bytes], bytes]:
    def edit(data: bytes) -> bytes:
        from omnirotor.px4.ulog_writer import patch_format

        return patch_format(data, topic, old, new)

    return edit


def _sparse_zeros(t: Path) -> None:
    from omnirotor.px4.ulog_writer import write_hover_log

    write_hover_log(t / "f.ulg")
    head = (t / "f.ulg").read_bytes()[:16]
    with (t / "f.ulg").open("wb") as fh:
        fh.write(head)
        fh.truncate(2 * 2**30)  # sparse: no disk used


def _airframe(value_line: str, name: str = "a", qgc: bool = False) -> Callable[[Path], None]:
    def setup(t: Path) -> None:
        lines = ["param set-default CA_ROTOR_COUNT 4"]
        for i, (x, y, km) in enumerate([(0.2, 0.2, 0.05), (-0.2, -0.2, 0.05), (0.2, -0.2, -0.05), (-0.2, 0.2, -0.05)]):
            for k, v in (("PX", x), ("PY", y), ("PZ", 0.0), ("KM", km), ("AX", 0.0), ("AY", 0.0), ("AZ", -1.0)):
                lines.append(f"param set-default CA_ROTOR{i}_{k} {v}")
        key, value = value_line.split()
        lines = [f"param set-default {key} {value}" if ln.split()[2] == key else ln for ln in lines]
        if qgc:
            lines = [f"1\t1\t{ln.split()[2]}\t{ln.split()[3]}\t9" for ln in lines]
        (t / name).write_text("\n".join(lines) + "\n")

    return setup


def _cut_last(data: bytes) -> bytes:
    return data[:-3]


def _start_time_max(data: bytes) -> bytes:
    return data[:8] + (2**64 - 1).to_bytes(8, "little") + data[16:]


def _deep(n: int) -> str:
    return "[" * n + "]" * n


def probes() -> list[Probe]:
    """Every probe, in the order of the table."""
    P = Probe
    zero_global = _maps(lambda d: d["global"].update(A=[[0.0] * 8] * 6))
    huge_entry = _maps(lambda d: d["global"]["A"][2].__setitem__(0, 1e308))
    rank_deficient = _maps(lambda d: d["regions"]["R1"]["A"].__setitem__(2, [0.0] * 8))
    return [
        # numbers too big, too small, or written oddly
        P(
            "numbers",
            "vehicle: integer mass of 400 digits",
            ("info", "--vehicle", "{t}/v.toml"),
            _vehicle("mass = 1.625", f"mass = {HUGE_INT}"),
        ),
        P("numbers", "vehicle: c_f = 1e308", ("info", "--vehicle", "{t}/v.toml"), _vehicle("c_f = ", "c_f = 1e308 #")),
        P(
            "numbers",
            "vehicle: omega_max_hz = 1e200",
            ("info", "--json", "--vehicle", "{t}/v.toml"),
            _vehicle("omega_max_hz = ", "omega_max_hz = 1e200 #"),
        ),
        P(
            "numbers",
            "vehicle: omega_min_hz = -1e200",
            ("info", "--json", "--vehicle", "{t}/v.toml"),
            _vehicle("omega_min_hz = ", "omega_min_hz = -1e200 #"),
        ),
        P("numbers", "--set with a 400-digit integer", ("run", "hover", "--set", f"observer.cutoff_hz={HUGE_INT}")),
        P(
            "numbers",
            "controller TOML with a 400-digit integer",
            ("run", "hover", "--config", "{t}/c.toml"),
            _write("c.toml", f"[observer]\ncutoff_hz = {HUGE_INT}\n"),
        ),
        P(
            "numbers",
            "campaign TOML with a 400-digit seed",
            ("campaign", "sliding", "--campaign", "{t}/c.toml", "--out", "{t}/o"),
            _write("c.toml", f'task = "sliding"\nseed = {HUGE_INT}\n'),
        ),
        P("numbers", "run --duration 1e9", ("run", "hover", "--duration", "1e9")),
        P("numbers", "run --duration 1e308", ("run", "hover", "--duration", "1e308")),
        P("numbers", "run --duration 1e-300", ("run", "hover", "--duration", "1e-300")),
        P("numbers", "run --duration 1_0 (underscores)", ("run", "hover", "--duration", "1_0")),
        P("numbers", "run --seed of 30 digits", ("run", "hover", "--seed", "9" * 30)),
        P(
            "numbers",
            "campaign --runs 1000000000000",
            ("campaign", "sliding", "--runs", "1000000000000", "--out", "{t}/o"),
        ),
        P("numbers", "campaign --workers 100000", ("campaign", "sliding", "--workers", "100000", "--out", "{t}/o")),
        P("numbers", "campaign --seed of 30 digits", ("campaign", "sliding", "--seed", "9" * 30, "--out", "{t}/o")),
        P("numbers", "reproduce --seed of 30 digits", ("reproduce", "--seed", "9" * 30, "--out", "{t}/o")),
        P("numbers", "identify --delta 1_6_0", ("identify", "{t}/h.csv", "--delta", "1_6_0"), _csv()),
        P("numbers", "identify --delta 1e400", ("identify", "{t}/h.csv", "--delta", "1e400"), _csv()),
        P(
            "numbers",
            "identify --weights 1_0,1,1,0,0,0",
            ("identify", "{t}/h.csv", "--weights", "1_0,1,1,0,0,0"),
            _csv(),
        ),
        # file formats
        P(
            "formats",
            "map JSON nested 100 000 deep",
            ("run", "sliding", "--map", "global", "--maps", "{t}/m.json"),
            _write("m.json", _deep(100_000)),
        ),
        P(
            "formats",
            "map JSON with a 5000-digit number",
            ("run", "sliding", "--map", "global", "--maps", "{t}/m.json"),
            _maps(raw=lambda s: s.replace('"delta": 3e-05', '"delta": ' + "1" * 5000)),
        ),
        P(
            "formats",
            "map JSON with an unknown key",
            ("run", "sliding", "--map", "global", "--maps", "{t}/m.json"),
            _maps(lambda d: d.update(bogus=1)),
        ),
        P(
            "formats",
            "map JSON with an unknown key in an entry",
            ("run", "sliding", "--map", "global", "--maps", "{t}/m.json"),
            _maps(lambda d: d["global"].update(Amat=1)),
        ),
        P(
            "formats",
            "map JSON with an all-zero global A",
            ("run", "sliding", "--map", "global", "--maps", "{t}/m.json"),
            zero_global,
        ),
        P(
            "formats",
            "map JSON with an entry of 1e308",
            ("run", "sliding", "--map", "global", "--maps", "{t}/m.json"),
            huge_entry,
        ),
        P(
            "formats",
            "map JSON with a rank-deficient region map",
            ("run", "sliding", "--map", "piecewise", "--maps", "{t}/m.json"),
            rank_deficient,
        ),
        P(
            "formats",
            "map JSON with a bare NaN",
            ("run", "sliding", "--map", "global", "--maps", "{t}/m.json"),
            _maps(raw=lambda s: s.replace('"delta": 3e-05', '"delta": NaN')),
        ),
        P(
            "formats",
            "map JSON with a string for n_rotors",
            ("run", "sliding", "--map", "global", "--maps", "{t}/m.json"),
            _maps(lambda d: d.update(n_rotors="8")),
        ),
        P(
            "formats",
            "vehicle TOML nested 100 000 deep",
            ("info", "--vehicle", "{t}/v.toml"),
            _write("v.toml", "a = " + _deep(100_000) + "\n"),
        ),
        P(
            "formats",
            "campaign TOML nested 100 000 deep",
            ("campaign", "sliding", "--campaign", "{t}/c.toml", "--out", "{t}/o"),
            _write("c.toml", "a = " + _deep(100_000) + "\n"),
        ),
        P("formats", "hover CSV with speeds 10x the limit", ("identify", "{t}/h.csv"), _csv(speed_scale=10.0)),
        P("formats", "hover CSV with a cell 1_6_0", ("identify", "{t}/h.csv"), _csv(cell="1_6_0")),
        P("formats", "hover CSV with a 5000-digit cell", ("identify", "{t}/h.csv"), _csv(cell="9" * 5000)),
        P(
            "formats",
            "hover .mat whose U is not u ⊗ I6 off the diagonal",
            ("identify", "{t}/h.mat"),
            _mat(off_diagonal=0.5),
        ),
        P("formats", "hover .mat with speeds 10x the limit", ("identify", "{t}/h.mat"), _mat(speed_scale=10.0)),
        P(
            "formats",
            "campaign-compare on a folder of garbage results",
            ("campaign-compare", "{t}/c", "--param", "gamma", "--out", "{t}/p.png"),
            _campaign_folder("not json\n"),
        ),
        P(
            "formats",
            "campaign-compare on results of wrong types",
            ("campaign-compare", "{t}/c", "--param", "gamma", "--out", "{t}/p.png"),
            _campaign_folder('{"index": 0, "params": 5, "success": "yes", "status": 3}\n'),
        ),
        P(
            "formats",
            "campaign-compare on a folder without results",
            ("campaign-compare", "{t}/c", "--param", "gamma", "--out", "{t}/p.png"),
            _dir("c"),
        ),
        P(
            "formats",
            "campaign-compare on results with a deep line",
            ("campaign-compare", "{t}/c", "--param", "gamma", "--out", "{t}/p.png"),
            _campaign_folder('{"index": 0, "params": ' + _deep(100_000) + "}\n"),
        ),
        # options a command would ignore
        P(
            "options",
            "run hover --map global --maps FILE",
            ("run", "hover", "--map", "global", "--maps", "{t}/m.json"),
            _good_maps,
        ),
        P("options", "run hover --maps FILE", ("run", "hover", "--maps", "{t}/m.json"), _good_maps),
        P("options", "run hover --blend smooth", ("run", "hover", "--blend", "smooth")),
        # outputs
        P("outputs", "run --out with a 300-byte name", ("run", "hover", "--out", "{t}/" + LONG)),
        P("outputs", "run --video with a 300-byte name", ("run", "hover", "--video", "{t}/" + LONG + ".mp4")),
        P("outputs", "identify --out with a 300-byte name", ("identify", "{t}/h.csv", "--out", "{t}/" + LONG), _csv()),
        P("outputs", "render --out with a 300-byte name", ("render", "wall", "--out", "{t}/" + LONG + ".png")),
        P("outputs", "reproduce --out with a 300-byte name", ("reproduce", "--out", "{t}/" + LONG)),
        P("outputs", "campaign --out with a 300-byte name", ("campaign", "sliding", "--out", "{t}/" + LONG)),
        P(
            "outputs",
            "campaign-compare --out with a 300-byte name",
            ("campaign-compare", "{t}/c", "--param", "gamma", "--out", "{t}/" + LONG + ".png"),
            _campaign_folder(""),
        ),
        P("outputs", "render --out an existing folder", ("render", "wall", "--out", "{t}/x.png"), _dir("x.png")),
        P(
            "outputs",
            "identify --out a FIFO",
            ("identify", "{t}/h.csv", "--out", "{t}/o.json"),
            _both(_csv(), _fifo("o.json")),
        ),
        P(
            "outputs",
            "identify --out a symbolic link",
            ("identify", "{t}/h.csv", "--out", "{t}/o.json"),
            _both(_csv(), _symlink("o.json", "target.json")),
        ),
        P("outputs", "identify --out /dev/full", ("identify", "{t}/h.csv", "--out", "/dev/full"), _csv()),
        P(
            "outputs",
            "identify --out under a regular file",
            ("identify", "{t}/h.csv", "--out", "{t}/f/o.json"),
            _both(_csv(), _write("f", "x")),
        ),
        P(
            "outputs",
            "campaign-compare --out under /proc",
            ("campaign-compare", "{t}/c", "--param", "gamma", "--out", "/proc/omnirotor.png"),
            _campaign_folder(_ONE_RUN, _DEFINITION),
        ),
        P(
            "outputs",
            "run --out a symbolic link to a file",
            ("run", "hover", "--out", "{t}/o"),
            _symlink("o", "target"),
        ),
        P(
            "outputs",
            "campaign-compare --out over an existing file",
            ("campaign-compare", "{t}/c", "--param", "gamma", "--out", "{t}/p.png"),
            _both(_campaign_folder(_ONE_RUN, _DEFINITION), _write("p.png", "old")),
            expect="note",
        ),
        # inputs that are not regular files
        P("inputs", "identify a FIFO named *.csv", ("identify", "{t}/p.csv"), _fifo("p.csv")),
        P(
            "inputs",
            "identify a folder holding a FIFO *.csv",
            ("identify", "{t}/d"),
            lambda t: (t / "d").mkdir() or os.mkfifo(t / "d" / "p.csv"),
        ),
        P(
            "inputs",
            "identify a link to /dev/zero named *.csv",
            ("identify", "{t}/z.csv"),
            lambda t: (t / "z.csv").symlink_to("/dev/zero"),
        ),
        P("inputs", "info --vehicle a FIFO", ("info", "--vehicle", "{t}/v.toml"), _fifo("v.toml")),
        P(
            "inputs",
            "run --maps a FIFO",
            ("run", "sliding", "--map", "global", "--maps", "{t}/m.json"),
            _fifo("m.json"),
        ),
        P("inputs", "run --config a FIFO", ("run", "hover", "--config", "{t}/c.toml"), _fifo("c.toml")),
        P(
            "inputs",
            "campaign --campaign a FIFO",
            ("campaign", "sliding", "--campaign", "{t}/c.toml", "--out", "{t}/o"),
            _fifo("c.toml"),
        ),
        P("inputs", "info --vehicle with a 300-byte name", ("info", "--vehicle", "{t}/" + LONG + ".toml")),
        P("inputs", "identify a file with a 300-byte name", ("identify", "{t}/" + LONG + ".csv")),
        # PX4 files (issue 26 item 2): the attack pass's failures
        P(
            "PX4 files",
            "ULog start time 2^64-1 µs",
            ("identify", "{t}/f.ulg", "--vehicle", "quadrotor"),
            _ulog(_start_time_max),
        ),
        P(
            "PX4 files",
            "ULog attitude q as char[16]",
            ("hover-windows", "{t}/f.ulg", "--vehicle", "quadrotor", "--out", "{t}/w.png"),
            _ulog(_fmt("vehicle_attitude", "float[4] q", "char[16] q")),
        ),
        P(
            "PX4 files",
            "ULog attitude q as uint8_t[16]",
            ("identify", "{t}/f.ulg", "--vehicle", "quadrotor"),
            _ulog(_fmt("vehicle_attitude", "float[4] q", "uint8_t[16] q")),
        ),
        P(
            "PX4 files",
            "ULog attitude q renamed",
            ("identify", "{t}/f.ulg", "--vehicle", "quadrotor"),
            _ulog(_fmt("vehicle_attitude", "float[4] q", "float[4] qq")),
        ),
        P(
            "PX4 files",
            "ULog time stamps stored as doubles",
            ("info", "--vehicle", "{t}/f.ulg"),
            _ulog(_fmt("esc_status", "uint64_t timestamp", "double timestamp")),
        ),
        P(
            "PX4 files",
            "ULog attitude array of 2^31 elements",
            ("identify", "{t}/f.ulg", "--vehicle", "quadrotor"),
            _ulog(_fmt("vehicle_attitude", "float[4] q", "float[2147483648] q")),
        ),
        P("PX4 files", "ULog: 2 GiB of zeros after the header (sparse)", ("identify", "{t}/f.ulg"), _sparse_zeros),
        P("PX4 files", "ULog cut inside its definitions", ("info", "--vehicle", "{t}/f.ulg"), _ulog(lambda d: d[:300])),
        P(
            "PX4 files",
            "ULog cut inside its last message",
            ("hover-windows", "{t}/f.ulg", "--vehicle", "quadrotor", "--out", "{t}/w.png"),
            _ulog(_cut_last),
            expect="note",
        ),
        P(
            "PX4 files",
            "ULog CA_ROTOR_COUNT = 100000000",
            ("info", "--vehicle", "{t}/f.ulg"),
            _ulog(rotor_count=100_000_000),
        ),
        P("PX4 files", "airframe CA_ROTOR0_PX = nan", ("info", "--vehicle", "{t}/a"), _airframe("CA_ROTOR0_PX nan")),
        P(
            "PX4 files",
            "airframe CA_ROTOR1_KM = 1e300",
            ("info", "--vehicle", "{t}/a"),
            _airframe("CA_ROTOR1_KM 1e300"),
        ),
        P(
            "PX4 files",
            "QGroundControl .params CA_ROTOR2_AZ = inf",
            ("info", "--vehicle", "{t}/a.params"),
            _airframe("CA_ROTOR2_AZ inf", "a.params", qgc=True),
        ),
        P(
            "PX4 files",
            "overlay with a 400-digit mass",
            ("info", "--vehicle", "{t}/a", "--vehicle-overlay", "{t}/o.toml"),
            _both(_airframe("CA_ROTOR0_PX 0.2"), _write("o.toml", f"mass = {HUGE_INT}\n")),
        ),
        # outputs (issue 26 item 3)
        P(
            "outputs",
            "hover-windows --out a FIFO",
            ("hover-windows", "{t}/f.ulg", "--vehicle", "quadrotor", "--out", "{t}/w.png"),
            _both(_ulog(), _fifo("w.png")),
        ),
        P(
            "outputs",
            "hover-windows --out a symbolic link",
            ("hover-windows", "{t}/f.ulg", "--vehicle", "quadrotor", "--out", "{t}/w.png"),
            _both(_ulog(), _symlink("w.png", "target.png")),
        ),
        P(
            "outputs",
            "hover-windows --csv /dev/null",
            ("hover-windows", "{t}/f.ulg", "--vehicle", "quadrotor", "--out", "{t}/w.png", "--csv", "/dev/null"),
            _ulog(),
        ),
        P(
            "outputs",
            "hover-windows --csv a FIFO (checked before the figure)",
            ("hover-windows", "{t}/f.ulg", "--vehicle", "quadrotor", "--out", "{t}/w.png", "--csv", "{t}/p.csv"),
            _both(_ulog(), _fifo("p.csv")),
        ),
        P("outputs", "run --ulog under /proc", ("run", "hover", "--duration", "0.1", "--ulog", "/proc/omnirotor.ulg")),
        P("outputs", "run --mcap under /proc", ("run", "hover", "--duration", "0.1", "--mcap", "/proc/omnirotor.mcap")),
        P(
            "outputs",
            "run --video under /proc",
            ("run", "hover", "--duration", "0.1", "--video", "/proc/omnirotor.mp4"),
        ),
        P(
            "outputs",
            "calibrate-truth --out a FIFO",
            ("calibrate-truth", "{t}/h.csv", "--out", "{t}/t.toml"),
            _both(_csv(), _fifo("t.toml")),
        ),
        # sizes built from options (issue 26 item 3)
        P(
            "sizes",
            "regions --from-signs --step 0.01",
            ("regions", "--from-signs", "--step", "0.01", "--out", "{t}/r.toml"),
        ),
        P(
            "sizes",
            "regions --from-signs --step 1e-9",
            ("regions", "--from-signs", "--step", "1e-9", "--out", "{t}/r.toml"),
        ),
        P(
            "sizes",
            "regions --from-signs --step 0.5 --bands 360",
            ("regions", "--from-signs", "--step", "0.5", "--bands", "360", "--out", "{t}/r.toml"),
        ),
        P(
            "sizes",
            "study points-per-region --workers 0",
            ("study", "points-per-region", "--out", "{t}/s", "--workers", "0"),
        ),
        P(
            "sizes",
            "study points-per-region --workers -1",
            ("study", "points-per-region", "--out", "{t}/s", "--workers", "-1"),
        ),
        P(
            "sizes",
            "study points-per-region --workers 100000",
            ("study", "points-per-region", "--out", "{t}/s", "--workers", "100000"),
        ),
        P(
            "sizes",
            "study points-per-region --validation -1",
            ("study", "points-per-region", "--out", "{t}/s", "--validation", "-1"),
        ),
        P("sizes", "study partitions --reps 0", ("study", "partitions", "--out", "{t}/s", "--reps", "0")),
        # the sessions that pair the node and its plant (issue 26 item 5): 1 to 16 hex digits, never 0
        *(
            P("pairing ids", f"{cmd} {option} {value!r}", (*argv, f"{option}={value}"))
            for cmd, argv, option, value in (
                ("fly", ("fly",), "--plant-session", "0"),
                ("fly", ("fly",), "--plant-session", "-1"),
                ("fly", ("fly",), "--plant-session", "10000000000000000"),  # 2**64
                ("fly", ("fly",), "--plant-session", "0x"),
                ("fly", ("fly",), "--session-id", "12 34"),
                ("fly", ("fly",), "--session-id", "0x0x1"),
                ("sim --serve", ("sim", "--serve", "--task", "hover"), "--pair-session", "xyz"),
                ("sim --serve", ("sim", "--serve", "--task", "hover"), "--session-id", "00000000"),
                ("px4-bridge", ("px4-bridge",), "--pair-session", "1.5"),
                ("px4-bridge", ("px4-bridge",), "--session-id", "1ffffffffffffffff"),
            )
        ),
    ]


# -- running -----------------------------------------------------------------------------------------------------


def _snapshot(folder: Path) -> dict[str, tuple]:
    out = {}
    for root, dirs, names in os.walk(folder):
        for n in dirs + names:
            p = Path(root) / n
            st = os.lstat(p)
            out[str(p.relative_to(folder))] = (st.st_mode, st.st_size, st.st_mtime_ns)
    return out


class _Timeout(Exception):
    """A probe ran past its alarm."""


@contextlib.contextmanager
def _captured():
    """Redirect file descriptors 1 and 2 into temporary files; yields a dict filled on exit."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = os.dup(1), os.dup(2)
    files = tempfile.TemporaryFile(), tempfile.TemporaryFile()
    result: dict[str, str] = {}
    os.dup2(files[0].fileno(), 1)
    os.dup2(files[1].fileno(), 2)
    py_streams = sys.stdout, sys.stderr  # may be a test runner's own objects, not the descriptors
    sys.stdout = open(1, "w", buffering=1, closefd=False)  # noqa: SIM115
    sys.stderr = open(2, "w", buffering=1, closefd=False)  # noqa: SIM115
    try:
        yield result
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        sys.stdout, sys.stderr = py_streams
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in saved:
            os.close(fd)
        for key, fh in zip(("out", "err"), files, strict=True):
            fh.seek(0)
            result[key] = fh.read().decode(errors="replace")
            fh.close()


def run_probe(probe: Probe, base: Path) -> tuple[str, str]:
    """Run one probe in a new folder under ``base``; returns (outcome, detail)."""
    from omnirotor.cli import main

    folder = Path(tempfile.mkdtemp(dir=base))
    if probe.setup is not None:
        probe.setup(folder)
    argv = [a.replace("{t}", str(folder)) for a in probe.argv]
    before = _snapshot(folder)
    cwd = os.getcwd()
    code: object = None

    def alarm(signum, frame):
        raise _Timeout

    old = signal.signal(signal.SIGALRM, alarm)
    signal.alarm(PROBE_TIMEOUT_S)
    os.chdir(folder)
    try:
        with _captured() as cap:
            try:
                code = main(argv)
            except _Timeout:
                code = "hung"
            except BaseException as exc:  # noqa: BLE001  (a probe classifies every escape)
                code = f"traceback ({type(exc).__name__})"
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)
        os.chdir(cwd)
    after = _snapshot(folder)
    err_lines = cap["err"].strip().splitlines()
    if isinstance(code, str):
        return code, cap["err"][-300:]
    if probe.expect == "note":
        ok = code == 0 and any(line.startswith("omnirotor: note:") for line in err_lines)
        return ("note, exit 0" if ok else f"exit {code} without a note"), cap["err"][-300:]
    if code != 2:
        return f"exit {code}", cap["err"][-300:]
    if len(err_lines) != 1 or not err_lines[0].startswith("omnirotor: error:") or cap["out"].strip():
        return "exit 2 with noise", cap["err"][-300:]
    if after != before:
        changed = sorted(set(after) ^ set(before) | {k for k in after if k in before and after[k] != before[k]})
        return "exit 2, files written", ", ".join(changed)[:200]
    return "one line, exit 2", err_lines[0]


GOOD = ("one line, exit 2", "note, exit 0")


def run_all(progress: Callable[[str], None] | None = None) -> list[tuple[Probe, str, str]]:
    """Run every probe; returns (probe, outcome, detail) in order."""
    os.environ.setdefault("MUJOCO_GL", "egl")
    results = []
    with tempfile.TemporaryDirectory(prefix="omnirotor-probes-") as base:
        for p in probes():
            outcome, detail = run_probe(p, Path(base))
            if progress is not None:
                progress(f"{outcome:>22}  {p.what}")
            results.append((p, outcome, detail))
    return results


GLITCH_SLOT_S = 2.5
"""Each sensor glitch gets its own slot of a hover run: 2 s to recover, checked over the last 0.5 s."""
GLITCH_TOL_M = 0.05
GLITCH_RECOVER_S = 2.0


def run_glitches() -> list[tuple[str, str, bool, bool, bool]]:
    """Fly every single-frame sensor glitch (``FRAME_GLITCHES``) into a hover, UKF and bypass (issue 14 item 1).

    Returns:
        ``(estimator, glitch, flagged with its cause, back within 5 cm within 2 s and nothing left flagged,
        every command finite and within the limits)`` for each glitch the estimator reads.
    """
    os.environ.setdefault("MUJOCO_GL", "egl")
    import numpy as np

    from omnirotor.control.supervisor import CAUSES
    from omnirotor.experiments.faults import FRAME_GLITCHES, glitch_fault
    from omnirotor.experiments.tasks.fault_hovers import glitch_hover
    from omnirotor.messages import ControlStatus
    from omnirotor.vehicle import load_vehicle

    vehicle, bit = load_vehicle(), dict(CAUSES)
    flags = int(ControlStatus.FRAME_REJECTED | ControlStatus.ESTIMATE_DEGRADED)
    rows = []
    for column, estimator in ((6, "ukf"), (7, "bypass")):
        glitches = [g for g in FRAME_GLITCHES if g[column] is not None]
        starts = [1.0005 + GLITCH_SLOT_S * i for i in range(len(glitches))]
        faults = [glitch_fault(g, t0) for g, t0 in zip(glitches, starts, strict=True)]
        run = glitch_hover(vehicle, estimator, faults, 1.0 + GLITCH_SLOT_S * len(glitches))
        t, err, status, cause, omega = run["t"], run["err"], run["status"], run["cause"], run["omega"]
        for i, g in enumerate(glitches):
            slot = (t >= starts[i] - 0.001) & (t < 1.0 + GLITCH_SLOT_S * (i + 1))
            back = slot & (t >= starts[i] + GLITCH_RECOVER_S)
            flagged = bool(np.any(cause[slot] & bit[g[column]]))
            recovered = bool(err[back].max() < GLITCH_TOL_M and not np.any(status[back] & flags))
            w = omega[slot]
            safe = bool(np.all(np.isfinite(w)) and w.min() >= vehicle.omega_min_hz and w.max() <= vehicle.omega_max_hz)
            rows.append((estimator, g[0], flagged, recovered, safe))
    return rows


NOISE_SEEDS = (0, 1, 2)
NOISE_CASES = ((2e-3, 1e-3), (3e-3, 1e-3), (5e-3, 1e-3), (10e-3, 1e-3), (20e-3, 1e-3), (1e-3, 5e-3))
"""``(true, told)`` motion-capture position noise, one sigma [m], of the closed-loop check (:func:`run_noise_matching`).
"""
NOISE_BEFORE_CM = {
    (2e-3, 1e-3): (0.102, 0.135, 0.103),
    (3e-3, 1e-3): (0.179, 0.271, 0.184),
    (5e-3, 1e-3): (0.624, 0.612, 0.430),
    (10e-3, 1e-3): (0.346, 0.570, 0.729),
    (20e-3, 1e-3): (0.826, 0.667, 0.778),
    (1e-3, 5e-3): (0.073, 0.080, 0.083),
}
"""The matched filter's errors [cm] per seed under the rule before the fix (commit 2c691ad: a running
average started at zero, P back to P0 once past 5 times the assumed sigma, no hysteresis), measured once by
:func:`run_noise_matching` on that commit."""
NOISE_GOAL = 1.5
"""The matched filter's error within this many times the reference's (told the truth; or without matching)."""


def run_noise_matching(
    progress: Callable[[str], None] | None = None,
) -> list[tuple[float, float, tuple[float, ...], tuple[float, ...]]]:
    """Fly the closed-loop check of the motion-capture noise matching: each case of ``NOISE_CASES``.

    Returns:
        ``(true [m], told [m], matched errors [cm] per seed, reference errors [cm] per seed)``; the reference is
        the filter told the true noise, or, where it was told more than the truth, the filter without matching.
    """
    os.environ.setdefault("MUJOCO_GL", "egl")
    from omnirotor.experiments.tasks.fault_hovers import mocap_noise_hover

    def err(true_m: float, told_m: float, matching: bool, seed: int) -> float:
        return round(mocap_noise_hover(true_m, told_m, matching, seed)[0], 3)

    rows = []
    for true_m, told_m in NOISE_CASES:
        if progress is not None:
            progress(f"noise matching: {true_m * 1e3:g} mm, told {told_m * 1e3:g} mm")
        matched = tuple(err(true_m, told_m, True, s) for s in NOISE_SEEDS)
        if told_m < true_m:
            ref = tuple(err(true_m, true_m, True, s) for s in NOISE_SEEDS)
        else:
            ref = tuple(err(true_m, told_m, False, s) for s in NOISE_SEEDS)
        rows.append((true_m, told_m, matched, ref))
    return rows


def _cells(xs: tuple[float, ...]) -> str:
    return " / ".join(f"{x:.3f}" for x in xs)


NOISE_ROW_PREFIX = "| noise "


def noise_rows_in(text: str) -> list[tuple[float, float, tuple[float, ...], tuple[float, ...]]]:
    """The rows of :func:`run_noise_matching` as a rendered docs/reliability.md reports them (to re-render it)."""
    rows = []
    for line in text.splitlines():
        if line.startswith(NOISE_ROW_PREFIX):
            cells = [c.strip() for c in line.strip("|").split("|")]
            true_mm, told_mm = (float(w) for w in cells[0].split()[1::3])
            rows.append(
                (
                    round(true_mm * 1e-3, 9),
                    round(told_mm * 1e-3, 9),
                    tuple(float(x) for x in cells[2].split(" / ")),
                    tuple(float(x) for x in cells[3].split(" / ")),
                )
            )
    return rows


def noise_section(rows: list[tuple[float, float, tuple[float, ...], tuple[float, ...]]]) -> list[str]:
    """The section on a motion capture noisier than the estimator assumes, with the closed-loop ``rows``."""
    lines = [
        "## A motion capture noisier than the estimator assumes",
        "",
        "Not a glitch but a wrong setting, and as dangerous: the UKF is told its motion capture's noise",
        "(`estimator.mocap_pos_std`, 1 mm; `mocap_att_std_deg`, 0.5°). Told 1 mm while the samples scatter by 10",
        "mm, it gated most samples out, re-initialised its pose from single noisy ones and fitted its velocity and",
        "biases to the noise: the closed-loop hover (10 s, clean plant, seeds 0 and 1) flew **23 and 24 m** away.",
        "The estimator matches the noise to its innovations (`_estimator_kernels.match_noise`, covariance matching",
        "per block, before the gate, so the gate and the update of a sample use the noise matched with it): the",
        "variance the innovations show beyond the state's own uncertainty, each sample counting at most 25 times",
        "the variance in use, is averaged: a plain mean of the samples and of 2 samples at the assumed variance",
        "(a noise as assumed raises it at its first sample with a probability of 1.4e-6) until its weight falls to",
        "1/50, then a running average over 50 samples.",
        "It replaces the assumed noise once above 4 times it (twice the one sigma), until it falls below 2.25",
        "times it (hysteresis), at most 30 times the one sigma. Each time the noise in use rises above the largest",
        "used in the episode, by a factor c, the covariance is discounted by c (each variance times",
        "min(c, P0/P), correlations kept): what was learnt from samples thought less noisy is worth c times less.",
        "Every period weighed so carries `ControlStatus.MOCAP_NOISE_RAISED`, counted in the run's",
        "`safety.flags.mocap_noise_raised`, and `omnirotor run` says it on stderr. A well-formed sample the filter",
        "does not fuse (outside its gate, too late) is flagged `MOCAP_REJECTED`.",
        "",
        "Why 5 mm kept 4 times the error of a filter told the noise, traced on the estimator's analytic flight",
        "(seed 0) and in the closed-loop hover: the running estimate started at zero and moved by 1/50 per",
        "sample, so for the first ~0.15 s the filter fused 5 mm samples as 1 mm ones, gated 17 of them out and",
        "fitted velocity and biases to the noise; it then overshot (21.8 mm at 0.3 s: the innovations held that",
        "corrupted state's error too) and took 3 s to come back to 5 mm, meanwhile trusting motion capture too",
        "little. The covariance reset (past 5 times the assumed sigma) came at 0.2 s, throwing away the biases;",
        "in closed loop the wrench observer's force estimate, which reads the estimate's `a_W`, was 0.3-0.4 N",
        "off that of the filter told the noise in the first second (the admittance's offset was the same in",
        "both), and the hover left its reference by up to 2.2 cm in z between 0.5 and 2 s (believed and true",
        "alike; the estimate itself was within 0.3 cm of the truth), which made the 0.62 cm (seed 0). The gate",
        "already used the matched noise. Now the noise is found within the first few samples, before velocity",
        "and biases are fitted to it. Without the covariance discount (the rest as now) the closed-loop hover",
        "kept up to 1.6, 1.8, 2.1 and 2.5 times the told filter's error at 2, 3, 10 and 20 mm; with 7 prior",
        "samples instead of 2 (slower to find the noise), up to 1.35 times at 3 to 20 mm and 1.74 at 2 mm; 2 mm,",
        "about the threshold, was switched on and off before the hysteresis (1.2 to 1.35 times the told filter's",
        "error, analytic flight).",
        "",
        "Hover, closed loop, 10 s, clean plant, largest per-axis RMS position error [cm], seeds "
        + " / ".join(str(s) for s in NOISE_SEEDS)
        + "; *before*:",
        "the rule before the fix (measured once); *reference*: the filter told the true noise, or, told more",
        "noise than there is, the filter without matching; *ratio*: now over reference, worst seed.",
        "Measured by `python tools/reliability_report.py` (`run_noise_matching`):",
        "",
        "| motion-capture noise | before | now | reference | ratio |",
        "|---|---|---|---|---|",
    ]
    for true_m, told_m, matched, ref in rows:
        before = NOISE_BEFORE_CM.get((true_m, told_m))
        ratio = max(m / r for m, r in zip(matched, ref, strict=True))
        lines.append(
            f"{NOISE_ROW_PREFIX}{true_m * 1e3:g} mm, told {told_m * 1e3:g} mm | "
            f"{_cells(before) if before else '-'} | {_cells(matched)} | {_cells(ref)} | {ratio:.2f} |"
        )
    n_ok = sum(max(m / r for m, r in zip(mt, rf, strict=True)) <= NOISE_GOAL for _, _, mt, rf in rows)
    lines += [
        "",
        f"**{n_ok} of {len(rows)} cases** within {NOISE_GOAL:g} times the reference. On the estimator alone (an",
        "analytic flight, `tests/test_estimator.py`) the matched filter flies within 1.02 times the one told the",
        "noise from the start-up on (2, 3, 5, 10, 20 mm; seeds 0 to 2), told 5 mm of a 1 mm motion capture it runs",
        "bit for bit as without matching, and a filter whose noise is as assumed runs bit for bit as without the",
        "matching (tested). In the default simulator the innovations show about 1 mm (0.3 mm of white noise plus",
        "latency jitter and the IMU's vibration), so the default 1 mm is never raised in the paper's experiments.",
        "",
        "",
    ]
    return lines


SUSTAINED_ROW_PREFIX = "| S"
SUSTAINED_FIGURE = "docs/img/sustained-faults.png"
_BOUND_TEXT = {
    "recover": "flagged, peak ≤ {peak:g} cm, back within 5 cm in 2 s",
    "track": "within 5 cm all along",
    "flag": "flagged ({cause}), peak ≤ {peak:g} cm",
    "land": "failsafe: lands within 1 m of where it began, never farther",
}


def run_sustained(progress: Callable[[str], None] | None = None) -> list[tuple[str, ...]]:
    """Fly every sustained fault of ``omnirotor.experiments.sustained_faults.SCENARIOS`` and draw the figure.

    Returns:
        One row of cells (strings, as rendered) per scenario: index, family, scenario, estimator, bound, peak
        distance from the reference [cm], time back within 5 cm after the fault's end [s], landing (offset from
        where the fault began and farthest on the way [m]), flagged, safe, outcome.
    """
    os.environ.setdefault("MUJOCO_GL", "egl")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from omnirotor.experiments import sustained_faults as sf
    from omnirotor.vehicle import load_vehicle

    runs = sf.run_all(load_vehicle(), progress=progress)
    rows = []
    for i, (sc, _run, v) in enumerate(runs):
        bound = _BOUND_TEXT[sc.bound].format(peak=sc.peak_m * 100, cause=sc.cause)
        back = "-" if sc.bound == "land" else ("never" if not np.isfinite(v["back_s"]) else f"{v['back_s']:.2f}")
        land = f"{v['land_offset_m']:.2f} / {v['away_m']:.2f}" if sc.bound == "land" else "-"
        rows.append(
            (
                f"S{i + 1}", sc.family, sc.name, sc.estimator, bound, f"{v['peak_m'] * 100:.1f}", back, land,
                "yes" if v["flagged"] else "no", "yes" if v["safe"] else "**no**",
                "met" if v["ok"] else "**not met**",
            )
        )  # fmt: skip
    families = list(dict.fromkeys(sc.family for sc, _, _ in runs))
    fig, axes = plt.subplots(len(families), 1, figsize=(9, 2.3 * len(families)), sharex=True)
    for ax, family in zip(axes, families, strict=True):
        for sc, run, v in runs:
            if sc.family != family:
                continue
            k = min(len(run["t"]), len(run["cause"]))
            t, err = run["t"][:k] - sf.T_FAULT_S, np.maximum(run["err"][:k], 1e-4)
            label = sc.name + ("" if v["ok"] else " (not met)")
            ax.semilogy(t, err * 100, lw=1.0, ls="-" if v["ok"] else "--", label=label)
        ax.axhline(sf.BACK_M * 100, color="k", lw=0.6, ls=":")
        ax.axvline(0.0, color="0.5", lw=0.6)
        ax.set_ylabel("distance from\nreference [cm]")
        ax.set_title(family, fontsize=9, loc="left")
        ax.legend(fontsize=6, loc="upper right", ncol=2)
        ax.set_xlim(-1.0, 12.0)
        ax.set_ylim(0.5, 500.0)
    axes[-1].set_xlabel("time from the fault's start [s] (dotted: 5 cm; a landing ends 1.3 m below its hover)")
    fig.tight_layout()
    fig.savefig(ROOT / SUSTAINED_FIGURE, dpi=110)
    plt.close(fig)
    return rows


def sustained_rows_in(text: str) -> list[tuple[str, ...]]:
    """The rows of :func:`run_sustained` as a rendered docs/reliability.md reports them (to re-render it)."""
    return [
        tuple(c.strip() for c in line.strip().strip("|").split("|"))
        for line in text.splitlines()
        if line.startswith(SUSTAINED_ROW_PREFIX) and line[len(SUSTAINED_ROW_PREFIX)].isdigit()
    ]


def sustained_section(rows: list[tuple[str, ...]]) -> list[str]:
    """The section on sustained sensor faults (issue 26 item 1) with the measured ``rows``."""
    n_met = sum(r[-1] == "met" for r in rows)
    lines = [
        "## Sustained sensor faults",
        "",
        "Issue 26 item 1: a fault that lasts, flown into the free scene's hover (compiled closed loop, clean",
        "plant, seed 1; the fault from 2 s on) by `omnirotor.experiments.sustained_faults` (the table of",
        "scenarios and their bounds; the injectors are the simulator's fault schedule: frozen, ramped, growing",
        "and randomly drawn signals besides NaN, inf, spikes and set values). What the controller does about them",
        "is in `src/omnirotor/control/supervisor.py` (jump checks against the IMU's prediction, frozen samples,",
        "the IMU coasting, the blind hold and the hold-then-land failsafe) and the UKF",
        "(`control/estimator.py`: coasting noise, drifting biases, biases beyond range flagged). *Peak*: the",
        "largest distance of the body from its hover reference from the fault on (a landing's includes its",
        "1.3 m descent); *back*: from the fault's end until it stays within 5 cm; *landed*: the offset from",
        "where the fault began, horizontally, at the end / the farthest on the way [m].",
        "`tests/test_sustained_faults.py` flies the same table and asserts each bound (the unmet ones are strict",
        "xfails with these figures).",
        "",
        f"**{n_met} of {len(rows)} scenarios** met their bound.",
        "",
        f"![Distance from the reference under each sustained fault]({SUSTAINED_FIGURE.removeprefix('docs/')})",
        "",
        "| # | family | scenario | estimator | bound | peak [cm] | back [s] | landed [m] | flagged | safe | outcome |",
        "|---|---|---|---|---|---:|---:|---:|---|---|---|",
    ]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    unmet = [r[2] for r in rows if r[-1] != "met"]
    if unmet:
        why = "Not met (the strict xfails of `tests/test_sustained_faults.py` say why): "
        lines += ["", why + "; ".join(unmet) + "."]
    lines += [
        "",
        "A bypass position drifting 1 mm per frame is told from a biased velocity by a third vote (SPEC §4.5's",
        "supervision): when the bypass velocity integrated over the window disagrees with the position's change,",
        "the velocity's change over the window is held against the IMU's acceleration integrated over it. The",
        "velocity changed as the IMU says, so the position drifts (`state_drift`): it is replaced by the position",
        "of one window before, moved on as the velocities say, until the received position agrees again. Without",
        "the vote the check took the disagreement for a velocity offset, subtracted it, and the controller",
        "followed the drifting position (1.29 m).",
        "",
        "The accelerometer bias ramps are followed because the UKF notices the drift: the running mean of its",
        "position innovations beyond 4 mm (or 5 standard deviations of that mean under the noise in use) scales",
        "its bias random walks by 1000 (`EstimatorParams.bias_drift_m`, `bias_drift_scale`). With the threshold",
        "at 5 times the noise in use (not the mean's deviation) and a factor of 100, the noise matching raised",
        "the noise first, the detector never fired and the 3 m/s² ramp peaked at 14.1 cm (10 m/s²: 1.39 m): the",
        "lagging bias estimate's `a_W` read as an external force to the wrench observer, which the free",
        "admittance yields to. The calibrated plant's innovations (about 1 mm) never reach 4 mm in the paper's",
        "experiments: `reproduce --quick` gives the same numbers.",
        "",
        "Before (the attack pass on c9bdaf9, on its own scenarios): a frozen motion capture flew 5.6 m away, a",
        "marker swap 14.4 m, a 200-frame blackout 6.5 m, an accelerometer running away 25 m, a clock reset 0.8 m,",
        "the accelerometer bias ramp 43 cm; on this branch before the fixes (the same table): the marker swap",
        "6.1 m, the 2 s blackout 11.9 m, the accelerometer running away 1.3 m, the bias ramp 11.2 m.",
        "",
        "",
    ]
    return lines


ISSUE26 = (
    # (item, category, probe groups counted here, test files that try it, who)
    ("1", "sustained sensor faults end safe and bounded", (), (), "rely"),
    ("2", "every PX4 file fails cleanly", ("PX4 files",), ("test_ulog_fuzz.py", "test_airframe_fuzz.py"), "rely"),
    (
        "3",
        "files, grids: outputs, temporary files, sizes, names read back",
        ("outputs", "sizes"),
        ("test_safe_io.py", "test_planted_links.py", "test_option_bounds.py", "test_round_trip_names.py"),
        "rely",
    ),
    ("3", "campaign files validated, campaign sizes", (), ("test_campaign_validation.py",), "exp"),
    ("4", "no code from the working folder, no trust in a peer's word", (), ("test_working_folder.py",), "exp"),
    (
        "5",
        "only the paired node commands the rotors, only its plant's frames are followed",
        ("pairing ids",),
        (
            "test_sitl_fuzz.py",
            "test_gate.py",
            "test_sitl_pairing.py",
            "test_fly_node.py",
            "test_sitl_armed.py",
            "test_zenoh_auth.py",
        ),
        "wire",
    ),
)
"""The categories of issue 26 and where each is tried (``render`` counts probes and tests)."""


def _landed(name: str) -> bool:
    """Whether a test file is in the tree (a category whose tests are not has not landed)."""
    return (ROOT / "tests" / name).is_file()


def issue26_section(results: list[tuple[Probe, str, str]], sustained: list[tuple[str, ...]]) -> list[str]:
    """The table of issue 26's categories: what was tried, how many, the outcome."""
    lines = [
        "## Issue 26: every category",
        "",
        "What the attack pass on c9bdaf9 broke (685 probes, 145 failures), category by category: the probes of",
        "this report that try it (for item 1 the scenarios flown), how many gave the promised outcome, and the",
        "test files that try it more widely",
        "(hypothesis and parametrised cases; each fails if the promise breaks, and the suite runs them). A",
        "category whose tests are not in the tree has not landed.",
        "",
        "| item | category | probes here | promised outcome | test files |",
        "|---|---|---:|---:|---|",
    ]
    for item, what, groups, files, _who in ISSUE26:
        mine = [o for p, o, _ in results if p.group in groups]
        good = sum(o in GOOD for o in mine)
        cells = ", ".join(f"`{f}`" if _landed(f) else f"`{f}`: not landed" for f in files)
        n, k = len(mine), good
        if item == "1":
            k, n = sum(r[-1] == "met" for r in sustained), len(sustained)
            cells = (
                f"`test_sustained_faults.py` ({'done' if k == n else 'partly done: the rest strict xfails'}; the"
                " scenarios: above)"
            )
        lines.append(f"| {item} | {what} | {n or '-'} | {k if n else '-'} | {cells or '-'} |")
    lines += ["", ""]
    return lines


def render(
    results: list[tuple[Probe, str, str]],
    glitches: list[tuple[str, str, bool, bool, bool]],
    noise: list[tuple[float, float, tuple[float, ...], tuple[float, ...]]],
    sustained: list[tuple[str, ...]],
) -> str:
    """The text of docs/reliability.md: the probes, the sensor glitches and the noise matching's check.

    Args:
        results: the probes' outcomes (:func:`run_all`).
        glitches: the sensor glitches' (:func:`run_glitches`).
        noise: the closed-loop check of the motion-capture noise matching (:func:`run_noise_matching`).
        sustained: the sustained faults' rows (:func:`run_sustained`).
    """
    groups: dict[str, list] = {}
    for p, outcome, _ in results:
        groups.setdefault(p.group, []).append((p, outcome))
    n_good = sum(outcome in GOOD for _, outcome, _ in results)
    lines = [
        "# Reliability: what was tried and what happened",
        "",
        "Generated by `python tools/reliability_report.py` (the test `tests/test_reliability_report.py` runs the",
        "same probes and fails if this file is not current). Each probe runs one `omnirotor` command on a bad",
        "input in a fresh folder; the promised outcome is *one line, exit 2*: exit status 2, one line on stderr,",
        "nothing on stdout, no file created, changed or removed. *note, exit 0* is an input accepted on purpose",
        "with what was assumed said on stderr. The documented maxima are in `src/omnirotor/limits.py`.",
        "",
        f"**{n_good} of {len(results)} probes** gave the promised outcome.",
        "",
        "| group | tried | one line, exit 2 | note, exit 0 | other outcome |",
        "|---|---:|---:|---:|---:|",
    ]
    for g, items in groups.items():
        c1 = sum(o == GOOD[0] for _, o in items)
        c2 = sum(o == GOOD[1] for _, o in items)
        lines.append(f"| {g} | {len(items)} | {c1} | {c2} | {len(items) - c1 - c2} |")
    lines += ["", "## Every probe", "", "| group | input | outcome |", "|---|---|---|"]
    for p, outcome, _ in results:
        lines.append(f"| {p.group} | {p.what} | {outcome} |")
    n_glitch_good = sum(all(r[2:]) for r in glitches)
    lines += [
        "",
        "## Sensor glitches in flight",
        "",
        "The controller's frame supervision (`src/omnirotor/control/supervisor.py`) checks every sensor frame.",
        "Each glitch below is one bad frame (a motion-capture glitch: one 100 Hz sample) injected by the",
        "simulator's fault schedule into a hover, one glitch every 2.5 s, with the estimator that reads it.",
        "Promised: the frame is rejected and *flagged* with its cause; the vehicle is *back* within 5 cm of its",
        "reference within 2 s with nothing left flagged; every command is *safe* (finite, within the rotor",
        "limits). Bursts, clock steps, long dropouts and random draws are in `tests/test_frame_supervision.py`.",
        "",
        f"**{n_glitch_good} of {len(glitches)} glitches** gave the promised outcome.",
        "",
        "| estimator | glitch | flagged | back | safe |",
        "|---|---|---|---|---|",
    ]
    for est, what, *ok in glitches:
        lines.append(f"| {est} | {what} | " + " | ".join("yes" if o else "**no**" for o in ok) + " |")
    lines += [
        "",
        *noise_section(noise),
        *sustained_section(sustained),
        *issue26_section(results, sustained),
        "## Beyond the probes",
        "",
        "Tested elsewhere, not counted above:",
        "",
        "- every file loader fed random bytes, corrupted and mutated valid files, huge integers, deep nesting,"
        " long names and special files (`tests/test_bad_input_hypothesis.py`, property-based);",
        "- safe writing: atomic replacement through a temporary file created exclusively under an unpredictable"
        " name, file modes from the umask, symbolic links and devices refused, `results.jsonl` appended without"
        " following links (`tests/test_safe_io.py`);",
        "- PX4 files: hypothesis over flipped bytes of the project's own and the real ULogs, truncation at every"
        " structural offset, format fields renamed, retyped and resized, huge declared sizes and times, through"
        " `hover-windows`, `identify` and `info` (`tests/test_ulog_fuzz.py`); airframes, QGroundControl `.params`"
        " files and overlays with values replaced, lines dropped and bytes flipped (`tests/test_airframe_fuzz.py`);",
        "- campaigns: SIGINT gives exit 130 with one line and keeps the results, the pool workers exit within"
        " seconds of a SIGKILLed main process, a second campaign into the same folder is refused, a run with"
        " non-finite steps is a failure, a plotting failure keeps `summary.json`"
        " (`tests/test_campaign_signals.py`); a campaign on a local Ray, resumed after its driver is killed"
        " (`tests/test_campaign_ray.py`).",
        "",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Run the probes; write docs/reliability.md, or with ``--check`` compare it."""
    args = sys.argv[1:] if argv is None else argv
    sys.path.insert(0, str(ROOT / "src"))
    results = run_all(progress=lambda s: print(s, file=sys.stderr))
    glitches = run_glitches()
    if "--check" in args or "--keep-noise" in args:  # the noise figures (33 hovers) re-read from the doc
        noise = noise_rows_in(DOC.read_text() if DOC.exists() else "")
    else:
        noise = run_noise_matching(progress=lambda s: print(s, file=sys.stderr))
    if "--check" in args or "--keep-sustained" in args:  # re-read from the doc; tests/test_sustained_faults.py
        sustained = sustained_rows_in(DOC.read_text() if DOC.exists() else "")
    else:
        sustained = run_sustained(progress=lambda s: print(s, file=sys.stderr))
    text = render(results, glitches, noise, sustained)
    if "--check" in args:
        current = DOC.read_text() if DOC.exists() else ""
        if current != text:
            print(f"{DOC} is not current: run python tools/reliability_report.py", file=sys.stderr)
            return 1
        return 0
    DOC.write_text(text)
    print(f"wrote {DOC}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
