"""The metrics comparison of issue 11 ("same numbers") finds what differs and nothing else."""

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent / "reference"))

from compare_metrics import differences, main  # noqa: E402

BASE = {
    "run": {
        "ee_rms_error": {"x_cm": 0.13721475538192612, "roll_deg": 0.0187},
        "controller_step_us_median": 4.9,
        "steps": 100,
        "lost": False,
        "first_loss_s": None,
        "true_mean_N": [3.4, 2.9],
        "figure": "/tmp/a/fig.png",
    }
}


def _with(path, value):
    data = json.loads(json.dumps(BASE))
    node = data["run"]
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    return data


def test_equal_metrics_and_ignored_fields():
    assert differences(BASE, BASE) == []
    assert differences(BASE, _with(["controller_step_us_median"], 9.9)) == []  # a wall-clock time
    assert differences(BASE, _with(["figure"], "/tmp/b/fig.png")) == []  # another --out folder
    assert differences(BASE, _with(["ee_rms_error", "x_cm"], 0.13721475538192612 * (1 + 5e-10))) == []


def test_every_kind_of_difference_is_reported():
    cases = [
        (["ee_rms_error", "x_cm"], 0.13721475538192612 * (1 + 2e-9)),
        (["steps"], 101),
        (["lost"], True),
        (["first_loss_s"], 1.0),
        (["true_mean_N"], [3.4]),
        (["true_mean_N"], [3.4, 2.91]),
        (["figure"], "/tmp/b/other.png"),
    ]
    for path, value in cases:
        diffs = differences(BASE, _with(path, value))
        assert len(diffs) == 1 and diffs[0].startswith("/run/" + path[0]), (path, diffs)
    extra = _with(["new_key"], 1.0)
    assert differences(BASE, extra) == ["/run/new_key: present in only one file"]


def test_command_line_exit_status(tmp_path, capsys):
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    a.write_text(json.dumps(BASE))
    b.write_text(json.dumps(_with(["steps"], 7)))
    assert main([str(a), str(a)]) == 0
    assert main([str(a), str(b)]) == 1
    assert "1 difference(s)" in capsys.readouterr().out
