"""The Table 1 errors in one compiled pass (issue 16): the batched formula to the last bit, no copies of the logs."""

import numpy as np
import pytest

from omnirotor.experiments.loop import TaskOptions, run_log
from omnirotor.experiments.metrics import AXES, RunLog, error_stats, pose_errors
from omnirotor.experiments.tasks import run_task


def _batched(log: RunLog, pose: str) -> np.ndarray:
    """The errors as the project first computed them (batched 3x3 products): the oracle."""
    p, R = (log.p_E_est_W, log.R_WE_est) if pose == "believed" else (log.p_E_W, log.R_WE)
    e = np.empty((log.t.size, 6))
    e[:, :3] = (p - log.p_Er_W) * 100.0
    M = np.einsum("nji,njk->nik", R, log.R_WEr)
    S = 0.5 * (M - np.transpose(M, (0, 2, 1)))
    e[:, 3], e[:, 4], e[:, 5] = S[:, 2, 1], S[:, 0, 2], S[:, 1, 0]
    e[:, 3:] = np.degrees(e[:, 3:])
    return e


@pytest.fixture(scope="module")
def hover_result():
    return run_task("hover", TaskOptions(duration_s=1.5, seed=3))


def _assert_stats_equal(log, mask, pose):
    rms, mx = error_stats(log, mask, pose)
    e = _batched(log, pose)
    e = e if mask is None else e[mask]
    want_rms, want_max = np.sqrt(np.mean(e * e, axis=0)), np.max(np.abs(e), axis=0)
    assert [rms[a] for a in AXES] == want_rms.tolist()  # bit for bit, not approximately
    assert [mx[a] for a in AXES] == want_max.tolist()


@pytest.mark.parametrize("pose", ["believed", "true"])
def test_error_stats_equal_the_batched_formula_on_a_run(hover_result, pose):
    log = run_log(hover_result.controller_log, hover_result.truth_log)
    for mask in (None, log.t >= 0.5, (log.t > 0.2) & (log.t < 0.9)):
        _assert_stats_equal(log, mask, pose)
    np.testing.assert_array_equal(pose_errors(log, pose), _batched(log, pose))


def _random_log(n: int, rng) -> RunLog:
    def rot(k):
        q = rng.standard_normal((k, 4))
        q /= np.linalg.norm(q, axis=1, keepdims=True)
        w, x, y, z = q.T
        return np.stack(
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
             2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
             2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], axis=1,
        ).reshape(k, 3, 3)  # fmt: skip

    vec = lambda: rng.standard_normal((n, 3)) * 0.1  # noqa: E731
    return RunLog(
        t=np.arange(n) * 1e-3, p_E_W=vec(), R_WE=rot(n), p_E_est_W=vec(), R_WE_est=rot(n), p_Er_W=vec(),
        R_WEr=rot(n), p_Ed_W=vec(), f_ext_hat_W=vec(), m_ext_hat_B=vec(), f_contact_W=vec(),
        in_contact=np.zeros(n, bool), region=np.zeros(n, int), omega_hz=np.zeros((n, 8)), status=np.zeros(n, int),
    )  # fmt: skip


@pytest.mark.parametrize("n", [1, 7, 4001])
def test_error_stats_equal_the_batched_formula_on_random_poses(n):
    rng = np.random.default_rng(n)
    log = _random_log(n, rng)
    for pose in ("believed", "true"):
        _assert_stats_equal(log, None, pose)
        _assert_stats_equal(log, rng.random(n) < 0.5 if n > 1 else None, pose)


def test_a_non_finite_error_reaches_the_statistics():
    rng = np.random.default_rng(0)
    log = _random_log(50, rng)
    log.p_E_est_W[10, 1] = np.nan
    log.R_WE_est[20, 0, 0] = np.inf
    rms, mx = error_stats(log)
    assert np.isnan(rms["y_cm"]) and np.isnan(mx["y_cm"])
    assert not np.isfinite(rms["pitch_deg"]) and not np.isfinite(mx["pitch_deg"])
    assert np.isfinite(rms["x_cm"]) and np.isfinite(mx["x_cm"])


def test_an_empty_mask_is_refused():
    log = _random_log(5, np.random.default_rng(1))
    with pytest.raises(ValueError, match="no sample"):
        error_stats(log, np.zeros(5, dtype=bool))


def test_run_log_views_the_logs_instead_of_copying(hover_result):
    ctl, truth = hover_result.controller_log, hover_result.truth_log
    log = run_log(ctl, truth)
    for arr, rec in (
        (log.t, ctl), (log.p_E_est_W, ctl), (log.R_WE_est, ctl), (log.R_WEr, ctl), (log.omega_hz, ctl),
        (log.p_E_W, truth), (log.R_WE, truth), (log.f_contact_W, truth),
    ):  # fmt: skip
        assert np.shares_memory(arr, rec.data)
    np.testing.assert_array_equal(log.R_WE.reshape(-1, 9), truth.group("R_WB"))
