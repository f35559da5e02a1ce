"""The simulator's stand-ins for controller-log rows that never arrived keep their own period's time.

A SITL run's controller log is the node's rows sent back over the wire (:mod:`omnirotor.sitl.server`); a row that
did not arrive is replaced at the run's end by the previous one (:func:`omnirotor.sitl.server.stand_in_rows`).
Its time column must say the period it stands for: a copied time stamp put two rows at the old instant for every
metric masked by time. The row store is fed directly here (the wire's loss is what the function is given).
"""

from __future__ import annotations

import numpy as np
import pytest

from omnirotor.control.controller import LOG_GROUPS
from omnirotor.errors import InputError
from omnirotor.recorder import Recorder
from omnirotor.sitl.server import stand_in_rows

DT = 0.001
T0 = 0.25  # the rows' trajectory time does not start at 0 in every task


def _log(n: int, seed: int = 0) -> tuple[Recorder, np.ndarray]:
    log = Recorder(n, LOG_GROUPS(6))
    rng = np.random.default_rng(seed)
    log.data[:] = rng.normal(size=log.data.shape)
    t = T0 + DT * np.arange(n)
    log.data[:, log.column_names.index("t")] = t
    log.n = n
    return log, t


@pytest.mark.parametrize(
    "dropped",
    [[3], [3, 4, 5, 6], [0, 1, 2], [17, 18, 19], [0, 5, 6, 11, 19]],
    ids=["one", "a run", "the first", "the last", "scattered"],
)
def test_stand_ins_take_their_own_period_time_and_the_previous_row_otherwise(dropped):
    n = 20
    log, t = _log(n)
    sent = log.data.copy()
    have = np.ones(n, dtype=bool)
    have[dropped] = False
    log.data[~have] = -1.0  # what the store holds where nothing arrived

    assert stand_in_rows(log, have, DT) == (len(dropped), 0)  # the count said (report.log_rows_missing)
    assert log.n == n

    col = log.column_names.index("t")
    got_t = log.data[:n, col]
    assert np.all(np.diff(got_t) > 0)  # strictly increasing: no two rows at one instant
    np.testing.assert_allclose(got_t, t, rtol=0, atol=1e-12)  # each at the period it stands for
    others = np.arange(log.n_signals) != col
    first = int(np.argmax(have))
    for j in range(n):
        if have[j]:
            np.testing.assert_array_equal(log.data[j], sent[j])  # received rows untouched
        else:  # the previous received row's values (the first received one before it)
            src = max(i for i in range(j + 1) if have[i]) if j > first else first
            np.testing.assert_array_equal(log.data[j, others], sent[src, others])


def test_no_row_at_all_is_refused_with_a_clear_error():
    log, _ = _log(5)
    with pytest.raises(InputError, match="no controller log rows"):
        stand_in_rows(log, np.zeros(5, dtype=bool), DT)


def test_nothing_missing_changes_nothing():
    log, _ = _log(8)
    before = log.data.copy()
    assert stand_in_rows(log, np.ones(8, dtype=bool), DT) == (0, 0)
    np.testing.assert_array_equal(log.data, before)


def test_after_a_failsafe_the_log_ends_with_the_nodes_last_row():
    """The node stopped (killed): the periods after its last row were never the controller's, so no stand-in is
    invented for them; a metric whose window lies there cannot be computed (the failsafe's path), and a gap before
    it is still stood in at its own time."""
    n = 30
    log, t = _log(n)
    have = np.ones(n, dtype=bool)
    have[[4, 5]] = False  # lost on the wire
    have[21:] = False  # the node is gone
    assert stand_in_rows(log, have, DT, end_at_last=True) == (11, 9)
    assert log.n == 21
    np.testing.assert_allclose(log.data[: log.n, log.column_names.index("t")], t[:21], rtol=0, atol=1e-12)
