"""Studies beyond the paper (its §6 next steps): partitions from sign patterns, points per region, torque rows.

Each study is a library function with a JSON result and a figure, run by ``omnirotor study ...``; the
results are in ``docs/beyond-the-paper.md``.
"""
