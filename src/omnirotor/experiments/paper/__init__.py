"""The paper's claims checked in simulation.

:mod:`.reproduce` (``omnirotor reproduce``), :mod:`.seeds` (each claim's goal over seeds), :mod:`.peg_wedge`
(the peg's friction wedge, an analysis behind one claim).
"""
