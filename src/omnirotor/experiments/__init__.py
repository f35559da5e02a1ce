"""The paper's experiments in simulation, and what is built on them.

Where a change goes:

* :mod:`~omnirotor.experiments.metrics`: what a run's logs say (SPEC §6);
* :mod:`~omnirotor.experiments.loop` (with its compiled stepping, :mod:`~omnirotor.experiments._loop`): the
  closed loop of the controller and the simulator, a task's options and result; beside it
  :mod:`~omnirotor.experiments.figures`, a run's plots;
* :mod:`~omnirotor.experiments.faults`: faults and perturbations of the plant;
* :mod:`~omnirotor.experiments.tasks`: the tasks of ``omnirotor run`` (an explicit table, one line per task);
* :mod:`~omnirotor.experiments.campaigns`: Monte-Carlo campaigns (the file's spec, the runner, the report);
* :mod:`~omnirotor.experiments.paper`: the paper's claims, ``omnirotor reproduce`` and its seeds;
* :mod:`~omnirotor.experiments.calibration`: the truth model's fit on real hover data and the disturbances'
  calibration.

Each layer imports only those above it in this list (``tests/test_import_layout.py``: no import cycles). This
package imports nothing itself, so ``omnirotor --help`` loads none of numpy, MuJoCo or numba.
"""
