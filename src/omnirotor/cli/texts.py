"""Help texts several commands share, written once."""

VEHICLE_HELP = (
    "Vehicle: a preset name (omnirotor, quadrotor, hexarotor-tilted), a vehicle TOML file, a PX4 airframe file "
    "(param set-default CA_* lines), a QGroundControl .params file or a PX4 ULog (its CA_* parameters)."
)
"""The ``--vehicle`` help: every format :func:`omnirotor.vehicle.load_vehicle` accepts."""
