"""PX4 in and out: flight logs (ULog) and airframes in, simulated runs out as ULog and MCAP.

Modules: :mod:`~omnirotor.px4.frames` (PX4's NED/FRD frames to ours, SPEC §1.1), :mod:`~omnirotor.px4.airframe`
(vehicles from ``CA_*`` parameters), :mod:`~omnirotor.px4.flight` (reading a ULog flight),
:mod:`~omnirotor.px4.windows` (automatic hover windows and hover points, SPEC §3.1),
:mod:`~omnirotor.px4.ulog_writer` (our own ULog writer), :mod:`~omnirotor.px4.run_export` (a run's signals, written
as ULog) and :mod:`~omnirotor.px4.mcap_export` (as MCAP). pyulog and mcap are imported inside functions only,
so importing this package stays cheap.
"""
