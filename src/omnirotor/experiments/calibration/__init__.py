"""Calibrations of the simulated plant.

:mod:`.truth` (the rotor-wake truth model fitted on the authors' real hover data, SPEC §7) and
:mod:`.disturbances` (the disturbances calibrated on a row of Table 1).
"""
