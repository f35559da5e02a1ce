"""Bad input everywhere: no file and no command-line option makes omnirotor fail with anything but InputError.

Property-based (hypothesis): every loader is fed random bytes, randomly corrupted bytes of a valid file,
valid files whose values, keys and structure were mutated (integers too big for a float among the values),
nesting up to 100 000 deep, FIFOs and devices in place of files, and names too long for the file system;
the only exception allowed is :class:`~omnirotor.errors.InputError`. Through the CLI, bad files and bad
options (durations, runs and seeds beyond the documented maxima of :mod:`omnirotor.limits`, numbers written
with underscores, output names over 255 bytes) give one line on stderr, exit status 2, and leave the output
folder or file absent.
"""

import contextlib
import dataclasses
import json
import math
import tempfile
from importlib.resources import files
from pathlib import Path

import numpy as np
import pytest
import scipy.io as sio
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from omnirotor.cli import main
from omnirotor.control.controller import ControllerParams, load_controller_params
from omnirotor.errors import InputError
from omnirotor.experiments.campaigns.runner import load_campaign
from omnirotor.identification import load_csv, load_mat, write_csv
from omnirotor.regions import load_partition
from omnirotor.sim.params import SimParams, load_sim_params
from omnirotor.so3 import rot_x, rot_y
from omnirotor.vehicle import load_vehicle
from omnirotor.wrench_maps import WrenchMapSet, load_wrench_maps

V = load_vehicle()
SETTINGS = settings(
    max_examples=60,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)

# -- valid files to mutate -------------------------------------------------------------------------------------


def toml_dumps(data: dict) -> str:
    """A small TOML writer (scalars, arrays, tables, arrays of tables): enough for the project's files."""

    def value(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, float):
            return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
        if isinstance(v, int):
            return str(v)
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(value(x) for x in v) + "]"
        if isinstance(v, dict):
            return "{" + ", ".join(f"{json.dumps(str(k))} = {value(x)}" for k, x in v.items()) + "}"
        return json.dumps(str(v))

    out: list[str] = []

    def table(d: dict, prefix: str) -> None:
        scalars = {k: v for k, v in d.items() if not _is_table(v) and not _is_table_array(v)}
        for k, v in scalars.items():
            out.append(f"{json.dumps(str(k))} = {value(v)}")
        for k, v in d.items():
            name = f"{prefix}.{json.dumps(str(k))}" if prefix else json.dumps(str(k))
            if _is_table(v):
                out.append(f"\n[{name}]")
                table(v, name)
            elif _is_table_array(v):
                for item in v:
                    out.append(f"\n[[{name}]]")
                    table(item, name)

    table(data, "")
    return "\n".join(out) + "\n"


def _is_table(v) -> bool:
    return isinstance(v, dict) and v != {}


def _is_table_array(v) -> bool:
    return isinstance(v, list) and v != [] and all(isinstance(x, dict) for x in v)


def _plain(obj):
    if dataclasses.is_dataclass(obj):
        return {f.name: _plain(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, tuple):
        return [_plain(x) for x in obj]
    return obj


def _preset(kind: str, name: str) -> str:
    return (files("omnirotor") / "presets" / kind / f"{name}.toml").read_text()


VALID_TOML = {
    "vehicle": _preset("vehicles", "omnirotor"),
    "partition": _preset("regions", "paper"),
    "controller": toml_dumps({k: v for k, v in _plain(ControllerParams()).items()}),
    "sim": toml_dumps(_plain(SimParams())),
    "campaign": _preset("campaigns", "default").replace("runs = 20", 'runs = 20\ntask = "sliding"'),
}


def _valid_maps_json() -> str:
    A = V.A_nom
    from omnirotor.wrench_maps import MapEntry

    maps = WrenchMapSet(
        vehicle="omnirotor",
        nominal=A,
        partition=load_partition(),
        regions={"R1": MapEntry(A * 1.1, 8, 0.01, 2.0), "R3": MapEntry(A * 1.05, 8, 0.02, 2.1)},
        global_=MapEntry(A * 1.08, 16, 0.1, 2.0),
        delta=3e-5,
        weights=(1.0, 1.0, 1.0, 0.0, 0.0, 0.0),
    )
    return json.dumps(maps.to_dict(), indent=1)


def _valid_csv(tmp: Path) -> str:
    Rs = [np.eye(3), rot_x(0.3), rot_y(-0.4)]
    omega = np.array([V.hover_input(R) for R in Rs])
    write_csv(tmp / "ok.csv", Rs, np.sign(omega) * np.sqrt(np.abs(omega)), ["R1", "R1", "R1"])
    return (tmp / "ok.csv").read_text()


def _valid_mat(tmp: Path, u: np.ndarray) -> bytes:
    n = u.shape[1]
    U = np.vstack([np.kron(row[None, :], np.eye(6)) for row in u])
    Z = np.tile([0.0, 0.0, V.weight, 0.0, 0.0, 0.0], u.shape[0])
    sio.savemat(tmp / "ok.mat", {"wMapStruct": {"U": U, "Z": Z}})
    assert U.shape == (6 * u.shape[0], 6 * n)
    return (tmp / "ok.mat").read_bytes()


LOADERS = {
    "vehicle": (".toml", lambda p: load_vehicle(p)),
    "partition": (".toml", lambda p: load_partition(p)),
    "controller": (".toml", lambda p: load_controller_params(p)),
    "sim": (".toml", lambda p: load_sim_params(p)),
    "campaign": (".toml", lambda p: load_campaign(p)),
    "maps": (".json", lambda p: load_wrench_maps(p, n_rotors=8)),
    "csv": (".csv", lambda p: load_csv(p, V)),
    "mat": (".mat", lambda p: load_mat(p, 8)),
}


def only_input_errors(kind: str, path: Path) -> None:
    """Call the loader; anything but success or InputError fails the test (with the input's kind)."""
    with contextlib.suppress(InputError):
        LOADERS[kind][1](path)


def test_the_valid_files_load(tmp_path):
    """The mutations below start from files that load (else the test would prove little)."""
    for kind, text in VALID_TOML.items():
        p = tmp_path / f"{kind}.toml"
        p.write_text(text)
        LOADERS[kind][1](p)
    (tmp_path / "m.json").write_text(_valid_maps_json())
    load_wrench_maps(tmp_path / "m.json", 8)
    _valid_csv(tmp_path)
    assert load_csv(tmp_path / "ok.csv", V).n_points == 3
    _valid_mat(tmp_path, np.array([V.hover_input()] * 2))
    assert load_mat(tmp_path / "ok.mat").n_points == 2


# -- random and corrupted bytes --------------------------------------------------------------------------------


@SETTINGS
@given(kind=st.sampled_from(sorted(LOADERS)), blob=st.binary(max_size=400))
def test_random_bytes_give_input_errors_only(tmp_path, kind, blob):
    p = tmp_path / f"random{LOADERS[kind][0]}"
    p.write_bytes(blob)
    only_input_errors(kind, p)


@st.composite
def corrupted(draw, data: bytes):
    """A valid file with bytes flipped, cut, inserted or lines shuffled."""
    b = bytearray(data)
    for _ in range(draw(st.integers(1, 6))):
        op = draw(st.sampled_from(["flip", "cut", "insert", "truncate", "dup_line", "drop_line"]))
        if not b:
            break
        i = draw(st.integers(0, len(b) - 1))
        if op == "flip":
            b[i] = draw(st.integers(0, 255))
        elif op == "cut":
            del b[i : i + draw(st.integers(1, 40))]
        elif op == "insert":
            b[i:i] = draw(st.sampled_from([b"nan", b"inf", b"-", b"\x00", b"\xff\xfe", b"\n", b",", b"=", b"[", b'"']))
        elif op == "truncate":
            del b[i:]
        else:
            lines = bytes(b).split(b"\n")
            j = draw(st.integers(0, len(lines) - 1))
            if op == "dup_line":
                lines.insert(j, lines[j])
            else:
                del lines[j]
            b = bytearray(b"\n".join(lines))
    return bytes(b)


@pytest.fixture(scope="module")
def valid_bytes(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("valid")
    out = {kind: text.encode() for kind, text in VALID_TOML.items()}
    out["maps"] = _valid_maps_json().encode()
    out["csv"] = _valid_csv(tmp).encode()
    out["mat"] = _valid_mat(tmp, np.array([V.hover_input(), V.hover_input(rot_x(0.2))]))
    return out


@SETTINGS
@given(data=st.data(), kind=st.sampled_from(sorted(LOADERS)))
def test_corrupted_valid_files_give_input_errors_only(tmp_path, valid_bytes, data, kind):
    blob = data.draw(corrupted(valid_bytes[kind]))
    p = tmp_path / f"corrupt{LOADERS[kind][0]}"
    p.write_bytes(blob)
    only_input_errors(kind, p)


# -- structured mutations of valid files -----------------------------------------------------------------------

WEIRD = st.one_of(
    st.sampled_from(
        [math.nan, math.inf, -math.inf, -1, 0, -0.0, 1e308, 1e-320, 10**30, -(10**30), 2**63, "", "x", True, False]
        + [10**400, -(10**400), 2**1024]  # integers too big for a float
    ),
    st.lists(st.sampled_from([1, 0.5, "a", math.nan, None, [1, 2]]), max_size=4),
    st.dictionaries(st.sampled_from(["a", "A", "dist", "low"]), st.sampled_from([1, "x", math.inf]), max_size=2),
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(),
    st.text(max_size=12),
)


def _paths(obj, prefix=()):
    yield prefix
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _paths(v, (*prefix, k))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _paths(v, (*prefix, i))


@st.composite
def mutated(draw, obj):
    """Replace, delete or add values at random places of a parsed file (values from WEIRD)."""
    obj = json.loads(json.dumps(obj))
    for _ in range(draw(st.integers(1, 4))):
        paths = list(_paths(obj))
        path = draw(st.sampled_from(paths))
        op = draw(st.sampled_from(["replace", "replace", "delete", "add_key", "wrap"]))
        if not path:
            if op == "add_key" and isinstance(obj, dict):
                obj[draw(st.sampled_from(["bogus", "task", "rotor", "region", "schema"]))] = draw(WEIRD)
            continue
        parent = obj
        for k in path[:-1]:
            parent = parent[k]
        key = path[-1]
        if op == "replace":
            parent[key] = draw(WEIRD)
        elif op == "delete":
            del parent[key]
        elif op == "wrap":
            parent[key] = [parent[key]]
        elif isinstance(parent[key], dict):
            parent[key][draw(st.sampled_from(["bogus", "low", "dist", "A", "mass"]))] = draw(WEIRD)
    return obj


def _parsed_toml(kind):
    import tomllib

    return tomllib.loads(VALID_TOML[kind])


@SETTINGS
@given(data=st.data(), kind=st.sampled_from(["vehicle", "partition", "controller", "sim", "campaign"]))
def test_mutated_toml_files_give_input_errors_only(tmp_path, data, kind):
    obj = data.draw(mutated(_parsed_toml(kind)))
    p = tmp_path / "mutated.toml"
    try:
        p.write_text(toml_dumps(obj))
    except (ValueError, UnicodeEncodeError):  # e.g. a lone surrogate: not writable as a text file at all
        return
    only_input_errors(kind, p)


@SETTINGS
@given(data=st.data())
def test_mutated_wrench_map_files_give_input_errors_only(tmp_path, data):
    obj = data.draw(mutated(json.loads(_valid_maps_json())))
    p = tmp_path / "mutated.json"
    p.write_text(json.dumps(obj))
    only_input_errors("maps", p)


CELLS = st.sampled_from(["nan", "inf", "-inf", "", "abc", "1e400", "-1e400", "0", "1", "-1", "  ", "1,2", "R99", "é"])


@SETTINGS
@given(data=st.data())
def test_mutated_csv_files_give_input_errors_only(tmp_path, data):
    rows = [line.split(",") for line in _valid_csv(tmp_path).strip().splitlines()]
    for _ in range(data.draw(st.integers(1, 4))):
        i = data.draw(st.integers(0, len(rows) - 1))
        op = data.draw(st.sampled_from(["cell", "cell", "add_col", "drop_col", "header"]))
        if op == "cell" and rows[i]:
            rows[i][data.draw(st.integers(0, len(rows[i]) - 1))] = data.draw(CELLS)
        elif op == "add_col":
            rows[i].append(data.draw(CELLS))
        elif op == "drop_col" and rows[i]:
            rows[i].pop(data.draw(st.integers(0, len(rows[i]) - 1)))
        else:
            rows[0][data.draw(st.integers(0, len(rows[0]) - 1))] = data.draw(st.sampled_from(["qw", "roll_deg", "x"]))
    p = tmp_path / "mutated.csv"
    p.write_text("\n".join(",".join(r) for r in rows) + "\n")
    only_input_errors("csv", p)


MAT_VALUES = st.one_of(
    st.sampled_from(["text", None]),
    st.builds(
        lambda shape, v: np.full(shape, v),
        st.sampled_from([(0,), (6,), (6, 48), (12, 48), (2, 3, 4)]),
        st.sampled_from([0.0, 1.0, np.nan, np.inf, 1e300]),
    ),  # fmt: skip
    st.builds(lambda n: np.arange(n, dtype=complex), st.integers(0, 12)),
)


@SETTINGS
@given(u_val=MAT_VALUES, z_val=MAT_VALUES, name=st.sampled_from(["wMapStruct", "other"]), drop=st.booleans())
def test_mutated_mat_files_give_input_errors_only(tmp_path, u_val, z_val, name, drop):
    content = {"U": u_val, "Z": z_val}
    if drop:
        content.pop("Z")
    content = {k: v for k, v in content.items() if v is not None}
    p = tmp_path / "mutated.mat"
    sio.savemat(p, {name: content} if content else {"x": 1.0})
    only_input_errors("mat", p)


# -- the command line ------------------------------------------------------------------------------------------


def cli(argv, capsys):
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def assert_one_line_exit_2(code, out, err):
    assert code == 2, (code, out, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("omnirotor: error:"), err
    assert "Traceback" not in out + err


@SETTINGS
@given(blob=st.binary(min_size=1, max_size=300), which=st.sampled_from(["vehicle", "config", "campaign", "maps"]))
def test_cli_garbage_files_exit_2_and_write_nothing(tmp_path, capsys, blob, which):
    if which in ("config", "campaign"):  # blank or comment-only garbage is a valid (default) file: not bad
        assume(not _parses_as_toml(blob))
    folder = Path(tempfile.mkdtemp(dir=tmp_path))  # the fixture's folder lives across examples
    bad = folder / ("bad.json" if which == "maps" else "bad.toml")
    bad.write_bytes(blob)
    out = folder / "out"
    if which == "vehicle":
        argv = ["info", "--vehicle", bad]
    elif which == "config":
        argv = ["run", "hover", "--config", bad, "--out", out]
    elif which == "campaign":
        argv = ["campaign", "sliding", "--campaign", bad, "--out", out]
    else:
        argv = ["run", "sliding", "--map", "global", "--maps", bad, "--out", out]
    assert_one_line_exit_2(*cli(argv, capsys))
    assert not out.exists()


def _parses_as_toml(blob: bytes) -> bool:
    import tomllib

    try:
        tomllib.loads(blob.decode())
    except (UnicodeDecodeError, tomllib.TOMLDecodeError):
        return False
    return True


BAD_OPTIONS = {
    "run": [
        ["--duration", "-1"],
        ["--duration", "0"],
        ["--duration", "nan"],
        ["--duration", "inf"],
        ["--duration", "soon"],
        ["--seed", "-3"],
        ["--seed", "1.5"],
        ["--solver", "gurobi"],
        ["--estimator", "kalman"],
        ["--truth", "magic"],
        ["--vehicle", "nope"],
        ["--set", "observer.nope=1"],
        ["--set", "observer.cutoff_hz"],
        ["--set", "observer.cutoff_hz=-5"],
        ["--map", "piecewise"],
        ["--map", "bent"],
        ["--blend", "soft"],
        ["--video", "film.avi"],
        ["--maps", "/no/such/maps.json"],
        ["--config", "/no/such/config.toml"],
    ],
    "campaign": [
        ["--runs", "0"],
        ["--runs", "-2"],
        ["--workers", "0"],
        ["--backend", "slurm"],
        ["--address", "10.0.0.1:6379"],
        ["--map", "global"],
        ["--maps", "/no/such.json"],
        ["--seed", "-1"],
        ["--campaign", "/no/such.toml"],
    ],
    "reproduce": [["--estimator", "kalman"], ["--workers", "0"], ["--workers", "100"]],
    "render": [["--width", "3"], ["--height", "99999"], ["--vehicle", "nope"]],
    "identify": [["--delta", "0"], ["--delta", "x"], ["--weights", "1,2,3"], ["--partition", "/no/such.toml"]],
}
TASK_ARG = {"run": ["sliding"], "campaign": ["sliding"], "reproduce": [], "render": ["wall"], "identify": []}


@settings(max_examples=40, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data(), command=st.sampled_from(sorted(BAD_OPTIONS)))
def test_cli_bad_options_exit_2_and_write_nothing(tmp_path, capsys, data, command):
    """One to three bad options (each bad on its own) on a command: an error, before anything is written."""
    picks = data.draw(st.lists(st.sampled_from(BAD_OPTIONS[command]), min_size=1, max_size=3, unique_by=tuple))
    tmp_path = Path(tempfile.mkdtemp(dir=tmp_path))
    out = tmp_path / ("out.png" if command == "render" else ("maps.json" if command == "identify" else "out"))
    argv = [command, *TASK_ARG[command]]
    if command == "identify":
        good = tmp_path / "ok.csv"
        if not good.exists():
            _valid_csv(tmp_path)
        argv.append(good)
    for p in picks:
        argv += p
    argv += ["--out", out]
    assert_one_line_exit_2(*cli(argv, capsys))
    assert not out.exists()


@pytest.mark.parametrize(
    "command,option", [(c, o) for c, opts in sorted(BAD_OPTIONS.items()) for o in opts], ids=lambda x: str(x)
)
def test_each_bad_option_alone_exits_2(tmp_path, capsys, command, option):
    out = tmp_path / ("out.png" if command == "render" else ("maps.json" if command == "identify" else "out"))
    argv = [command, *TASK_ARG[command]]
    if command == "identify":
        _valid_csv(tmp_path)
        argv.append(tmp_path / "ok.csv")
    assert_one_line_exit_2(*cli([*argv, *option, "--out", out], capsys))
    assert not out.exists()


def test_cli_out_that_is_a_file_is_refused_and_kept(tmp_path, capsys):
    f = tmp_path / "taken"
    f.write_text("mine")
    for argv in (["run", "hover", "--out", f], ["campaign", "sliding", "--out", f], ["reproduce", "--out", f]):
        assert_one_line_exit_2(*cli(argv, capsys))
        assert f.read_text() == "mine"


# -- issue 14: huge numbers, deep nesting, special files, long names, documented maxima -----------------------


def _nested(kind: str, depth: int) -> str:
    inner = "[" * depth + "]" * depth
    if kind == "maps":
        return '{"schema": "omnirotor/wrench-maps", "version": 1, "n_rotors": 8, "nominal": ' + inner + "}"
    if kind == "csv":
        return "qw,qx,qy,qz\n" + inner + "\n"
    if kind == "mat":
        return inner
    return "a = " + inner + "\n"


@SETTINGS
@given(kind=st.sampled_from(sorted(LOADERS)), depth=st.sampled_from([65, 1000, 100_000]))
def test_deeply_nested_files_give_input_errors_only(tmp_path, kind, depth):
    p = tmp_path / f"deep{LOADERS[kind][0]}"
    p.write_text(_nested(kind, depth))
    only_input_errors(kind, p)


@SETTINGS
@given(digits=st.integers(310, 6000), where=st.sampled_from(["delta", "A", "points", "weights"]))
def test_huge_numbers_in_map_files_give_input_errors_only(tmp_path, digits, where):
    d = json.loads(_valid_maps_json())
    if where == "A":
        d["global"]["A"][0][0] = "BIG"
    elif where == "weights":
        d["weights"][0] = "BIG"
    elif where == "points":
        d["global"]["points"] = "BIG"
    else:
        d["delta"] = "BIG"
    text = json.dumps(d).replace('"BIG"', "7" * digits)
    p = tmp_path / "big.json"
    p.write_text(text)
    with pytest.raises(InputError):
        load_wrench_maps(p, 8)


@pytest.mark.parametrize("kind", sorted(LOADERS))
@pytest.mark.parametrize("special", ["fifo", "device", "folder", "long-name"])
def test_special_files_are_refused_at_once(tmp_path, kind, special):
    """A FIFO, a device, a folder or a 300-byte name in place of a file: an InputError, never a wait."""
    import os
    import signal

    p = tmp_path / f"x{LOADERS[kind][0]}"
    if special == "fifo":
        os.mkfifo(p)
    elif special == "device":
        p.symlink_to("/dev/zero")
    elif special == "folder":
        p.mkdir()
    else:
        p = tmp_path / ("n" * 300 + LOADERS[kind][0])

    def hung(signum, frame):
        raise AssertionError(f"{kind} loader blocked on a {special}")

    old = signal.signal(signal.SIGALRM, hung)
    signal.alarm(20)
    try:
        with pytest.raises(InputError):
            LOADERS[kind][1](p)
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def _beyond(low, high):
    return st.one_of(
        st.floats(min_value=high, exclude_min=True, allow_infinity=False),
        st.floats(max_value=low, exclude_max=True, allow_infinity=False),
        st.sampled_from([1e9, 1e308, 1e-300, -0.0]),
    )


@settings(max_examples=25, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_values_beyond_the_documented_maxima_exit_2(tmp_path, capsys, data):
    from omnirotor.limits import MAX_CAMPAIGN_RUNS, MAX_DURATION_S, MAX_SEED, MIN_DURATION_S

    folder = Path(tempfile.mkdtemp(dir=tmp_path))
    out = folder / "out"
    which = data.draw(st.sampled_from(["duration", "runs", "seed", "workers", "underscore", "set"]))
    if which == "duration":
        argv = ["run", "hover", "--duration", repr(data.draw(_beyond(MIN_DURATION_S, MAX_DURATION_S)))]
    elif which == "runs":
        argv = ["campaign", "sliding", "--runs", str(data.draw(st.integers(MAX_CAMPAIGN_RUNS + 1, 10**30)))]
    elif which == "seed":
        cmd = data.draw(st.sampled_from([["run", "hover"], ["campaign", "sliding"], ["reproduce"]]))
        argv = [*cmd, "--seed", str(data.draw(st.integers(MAX_SEED + 1, 10**60)))]
    elif which == "workers":
        argv = ["campaign", "sliding", "--workers", str(data.draw(st.integers(257, 10**12)))]
    elif which == "underscore":
        argv = ["run", "hover", "--duration", data.draw(st.sampled_from(["1_0", "2_5.0", "1_000"]))]
    else:
        argv = ["run", "hover", "--set", f"observer.cutoff_hz={data.draw(st.integers(10**309, 10**400))}"]
    assert_one_line_exit_2(*cli([*argv, "--out", out], capsys))
    assert not out.exists()


@settings(max_examples=12, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(n=st.integers(256, 1000), command=st.sampled_from(["run", "campaign", "reproduce", "render", "identify"]))
def test_output_names_too_long_exit_2(tmp_path, capsys, n, command):
    folder = Path(tempfile.mkdtemp(dir=tmp_path))
    name = "o" * n + (".png" if command == "render" else ".json" if command == "identify" else "")
    argv = {"run": ["run", "hover"], "campaign": ["campaign", "sliding"], "reproduce": ["reproduce"],
            "render": ["render", "wall"], "identify": ["identify", "ok.csv"]}[command]  # fmt: skip
    if command == "identify":
        _valid_csv(folder)
        argv = ["identify", folder / "ok.csv"]
    assert_one_line_exit_2(*cli([*argv, "--out", folder / name], capsys))
    assert sorted(p.name for p in folder.iterdir()) == (["ok.csv"] if command == "identify" else [])
