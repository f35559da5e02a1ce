"""Every size a command builds from its options is bounded before any work (issue 26 item 3).

Beyond the documented maxima of :mod:`omnirotor.limits`, and for counts that make no sense (0, -1), each
command gives one line on stderr, exit status 2, and writes nothing; a refused value never starts a pool or
allocates a grid (each case returns within seconds, long before the work it would have started).
"""

import pytest

from omnirotor.cli import main

CASES = [
    (["regions", "--from-signs", "--step", "0.01", "--out", "{t}/r.toml"], "finer than the finest grid"),
    (["regions", "--from-signs", "--step", "1e-9", "--out", "{t}/r.toml"], "finer than the finest grid"),
    (["regions", "--from-signs", "--step", "0.5", "--bands", "360", "--out", "{t}/r.toml"], "finer than the"),
    (["regions", "--from-signs", "--bands", "360", "--out", "{t}/r.toml"], "--bands must be an integer from 1 to"),
    (["regions", "--from-signs", "--bands", "0", "--out", "{t}/r.toml"], "--bands must be an integer from 1 to"),
    (["study", "points-per-region", "--out", "{t}/s", "--workers", "0"], "--workers must be an integer from 1"),
    (["study", "points-per-region", "--out", "{t}/s", "--workers", "-1"], "--workers must be an integer from 1"),
    (["study", "points-per-region", "--out", "{t}/s", "--workers", "100000"], "--workers must be an integer from 1"),
    (["study", "points-per-region", "--out", "{t}/s", "--validation", "-1"], "--validation must be an integer"),
    (["study", "points-per-region", "--out", "{t}/s", "--validation", "10000000"], "--validation must be an integer"),
    (["study", "points-per-region", "--out", "{t}/s", "--reps", "1000000000"], "--reps must be an integer"),
    (["study", "points-per-region", "--out", "{t}/s", "--counts", "3,100000000"], "points per region must be"),
    (["study", "partitions", "--out", "{t}/s", "--validation", "-1"], "--validation must be an integer"),
    (["study", "partitions", "--out", "{t}/s", "--validation", "0"], "--validation must be an integer"),
    (["study", "partitions", "--out", "{t}/s", "--reps", "0"], "--reps must be an integer"),
    (["study", "partitions", "--out", "{t}/s", "--total", "1000000000"], "--total must be an integer"),
]


@pytest.mark.parametrize("argv,words", CASES, ids=lambda c: " ".join(c) if isinstance(c, list) else None)
def test_sizes_beyond_the_documented_maxima_are_refused(tmp_path, capsys, argv, words):
    code = main([a.replace("{t}", str(tmp_path)) for a in argv])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("omnirotor: error:") and words in err[0], err
    assert list(tmp_path.iterdir()) == []
