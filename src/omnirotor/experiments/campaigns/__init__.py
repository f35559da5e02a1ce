"""Monte-Carlo campaigns (``omnirotor campaign``).

:mod:`.spec` reads a campaign file and draws each run's options, :mod:`.runner` flies the runs on a process pool
or Ray and keeps the results, :mod:`.report` summarises and plots a campaign folder.
"""
