"""Runs sent to the workers in chunks (issue 16): every run once, in order, shrinking to single runs at the end."""

import pytest

from omnirotor.experiments.campaigns.runner import CHUNK_MAX, chunk_sizes, run_chunk


@pytest.mark.parametrize("workers", [1, 2, 3, 8])
@pytest.mark.parametrize("n", [1, 2, 5, 17, 200, 1001])
def test_chunks_cover_every_run_once_and_shrink_to_one(n, workers):
    sizes = chunk_sizes(n, workers)
    assert sum(sizes) == n
    assert all(1 <= k <= CHUNK_MAX for k in sizes)
    assert sizes == sorted(sizes, reverse=True)  # the tail is made of the small ones
    assert sizes[-1] == 1
    if n >= 8 * CHUNK_MAX * workers:  # a long campaign: far fewer requests than runs
        assert len(sizes) < n / 3


def test_a_chunk_runs_its_jobs_in_order():
    assert run_chunk(lambda job: {"index": job}, [3, 1, 2]) == [{"index": 3}, {"index": 1}, {"index": 2}]
