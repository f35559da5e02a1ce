"""The documented maxima of omnirotor's inputs, in one place (issue 14, "Bad input").

A value beyond one of these is refused with one line on stderr and exit status 2 before anything runs, rather
than allocating terabytes or running for years. The README's command-line section quotes them.
"""

from __future__ import annotations

__all__ = [
    "MIN_DURATION_S",
    "MAX_DURATION_S",
    "MAX_CAMPAIGN_RUNS",
    "MAX_WORKERS",
    "MAX_SEED",
    "MAX_INPUT_BYTES",
    "MAX_JSON_DEPTH",
    "SPEED_MARGIN",
    "MAX_ULOG_BYTES",
    "MAX_ULOG_TIME_US",
    "MAX_ROTORS",
    "MIN_SIGN_STEP_DEG",
    "MAX_SIGN_BANDS",
    "MAX_STUDY_REPS",
    "MAX_VALIDATION_ATTITUDES",
    "MAX_STUDY_POINTS",
]

MIN_DURATION_S = 0.01
"""Shortest simulated run [s] (10 controller periods): shorter runs have no metrics to report."""
MAX_DURATION_S = 600.0
"""Longest simulated run [s]: its logs at 1 kHz take about 1 GB of memory."""
MAX_CAMPAIGN_RUNS = 100_000
"""Most runs in one campaign (about 1 s to a minute each)."""
MAX_WORKERS = 256
"""Most parallel workers of a campaign or of ``reproduce``."""
MAX_SEED = 2**63 - 1
"""Largest seed (seeds are integers >= 0)."""
MAX_INPUT_BYTES = 256 * 2**20
"""Largest input file read (vehicle, controller, campaign, map, hover data) [bytes]."""
MAX_JSON_DEPTH = 64
"""Deepest nesting of arrays and objects in an input JSON file (the wrench-map files need 4)."""
SPEED_MARGIN = 1.05
"""Hover data whose rotor speeds exceed the vehicle's limits by more than this factor are refused."""
MAX_ULOG_BYTES = 2 * 2**30
"""Largest PX4 flight log read [bytes] (a long flight at PX4's highest logging rate is a few hundred MB; pyulog
holds a log's data in memory about twice over)."""
MAX_ULOG_TIME_US = 2**53
"""Latest time stamp in a ULog [µs] (about year 2255 as Unix time; exact as a float64, so times convert safely)."""
MAX_ROTORS = 64
"""Most rotors of a vehicle (PX4's control allocation takes 12; ``CA_ROTOR_COUNT`` beyond this is refused)."""
MIN_SIGN_STEP_DEG = 2.5
"""Finest grid of ``regions --from-signs`` [deg] (72 x 144 cells). The search's time grows about as the square
of the rows and the 1.7th power of the bands: on a loaded 2-core machine 5 deg and 4 bands (the defaults) took
3 s, 2 deg 17 s, 1 deg over a minute, 2 deg and 12 bands 140 s; 0.01 deg would need 648 million cells."""
MAX_SIGN_BANDS = 8
"""Most elevation bands of ``regions --from-signs`` (5 deg and 12 bands took 19 s; the worst allowed, 2.5 deg and
8 bands, 44 s beside a test run)."""
MAX_STUDY_REPS = 1000
"""Most seeded repetitions of a study (``study ... --reps``)."""
MAX_VALIDATION_ATTITUDES = 100_000
"""Most validation attitudes of a study (``--validation``)."""
MAX_STUDY_POINTS = 10_000
"""Most hover points per region (``study points-per-region --counts``) or in total (``study partitions --total``)."""
