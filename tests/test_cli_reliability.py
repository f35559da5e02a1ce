"""The command line's error paths (issue 14): warnings, Ctrl-C, MuJoCo's log, --out over an existing file."""

import os
import warnings

import pytest

import omnirotor.cli as cli
from omnirotor.errors import InputError


def fake_app(action):
    def app(args=None, standalone_mode=True):
        return action()

    return app


def run(monkeypatch, capsys, action):
    cli._register()  # the commands register on the real app before it is replaced
    monkeypatch.setattr(cli, "app", fake_app(action))
    code = cli.main([])
    out = capsys.readouterr()
    return code, out.out, [x for x in out.err.splitlines() if x.strip()]


def test_warnings_before_an_error_leave_only_the_error_line(monkeypatch, capsys):
    def action():
        warnings.warn("overflow encountered in multiply", RuntimeWarning, stacklevel=1)
        raise InputError("bad value")

    code, _, err = run(monkeypatch, capsys, action)
    assert code == 2 and err == ["omnirotor: error: bad value"]


def test_numerical_warnings_of_a_success_are_one_note_and_others_are_dropped(monkeypatch, capsys):
    def action():
        for _ in range(3):
            warnings.warn("invalid value encountered in divide", RuntimeWarning, stacklevel=1)
        warnings.warn("No artists with labels found", UserWarning, stacklevel=1)

    code, _, err = run(monkeypatch, capsys, action)
    assert code == 0 and len(err) == 1
    assert err[0].startswith("omnirotor: note: 3 numerical warning(s)") and "divide" in err[0]


def test_ctrl_c_during_a_compiled_modules_import_is_exit_130_with_one_line(monkeypatch, capsys):
    # what pybind11 raises when Ctrl-C lands in a module's initialisation (seen with mujoco._specs)
    def action():
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as exc:
            raise ImportError("initialization failed") from exc

    code, _, err = run(monkeypatch, capsys, action)
    assert code == 130 and err == ["omnirotor: interrupted"]


def test_a_real_import_error_is_not_taken_for_ctrl_c(monkeypatch, capsys):
    def action():
        raise ImportError("No module named 'nothing_here'")

    with pytest.raises(ImportError, match="nothing_here"):
        run(monkeypatch, capsys, action)
    assert "interrupted" not in capsys.readouterr().err  # a bug's traceback, not a Ctrl-C's exit 130


@pytest.mark.parametrize("how", ["keyboard", "typer-exit"])
def test_ctrl_c_is_exit_130_with_one_line(monkeypatch, capsys, how):
    import typer

    def action():
        if how == "keyboard":
            raise KeyboardInterrupt
        return 130  # what typer returns outside standalone mode after catching Ctrl-C

    if how == "typer-exit":
        action_ = action
    else:

        def action_():
            try:
                action()
            except KeyboardInterrupt:
                raise typer.Exit(130) from None

    code, _, err = run(monkeypatch, capsys, action_)
    assert code == 130 and len(err) == 1 and err[0].startswith("omnirotor: interrupted")


def test_mujoco_log_goes_under_the_folder_or_nowhere(tmp_path, monkeypatch):
    import mujoco

    from omnirotor.safe_io import route_mujoco_log

    saved = mujoco.MjLogConfig.get()
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    monkeypatch.chdir(cwd)
    model = mujoco.MjModel.from_xml_string(
        "<mujoco><worldbody><body><freejoint/><geom size='.1'/></body></worldbody></mujoco>"
    )

    def unstable_step():
        data = mujoco.MjData(model)
        data.qpos[0] = float("nan")  # MuJoCo warns: "Nan, Inf or huge value in QPOS"
        mujoco.mj_step(model, data)

    try:
        out = tmp_path / "out"
        out.mkdir()
        route_mujoco_log(out)
        unstable_step()
        assert "QPOS" in (out / "MUJOCO_LOG.TXT").read_text()
        route_mujoco_log(None)
        unstable_step()
        assert os.listdir(cwd) == []
        assert (out / "MUJOCO_LOG.TXT").read_text().count("QPOS") == 1
    finally:
        saved.set()


def test_replacing_an_existing_output_file_is_said(tmp_path, capsys):
    import json

    folder = tmp_path / "c"
    folder.mkdir()
    definition = {"task": "sliding", "vary": {"gamma": {}}, "options": {"map": "nominal"}}
    (folder / "campaign.json").write_text(json.dumps({"hash": "0" * 64, "definition": definition}))
    run_line = {"index": 0, "status": "ok", "params": {"gamma": 4.0}, "success": True, "metrics": {}}
    (folder / "results.jsonl").write_text(json.dumps(run_line) + "\n")
    png = tmp_path / "p.png"
    png.write_text("old")
    code = cli.main(["campaign-compare", str(folder), "--param", "gamma", "--out", str(png)])
    err = capsys.readouterr().err
    assert code == 0 and png.read_bytes()[:4] == b"\x89PNG"
    assert "replaced the existing file" in err
