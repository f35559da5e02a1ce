"""Sensor-frame supervision: the first stage of the controller's 1 kHz step (issue 14; SPEC §4.5).

Every frame record (:mod:`omnirotor.messages`) is checked before the estimator reads it, and the checked copy
(:attr:`STATE_DTYPE` field ``clean``, a :data:`~omnirotor.messages.FRAME_HEAD_DTYPE` record: the frame without
its rotor speeds) is what the estimator gets. A part
that fails a check is *rejected*: its cause is a bit of ``cause`` (the ``CAUSE_*`` constants, logged per step
in the controller log's ``frame_reject`` column and counted per cause in ``counts``), the command of that
period carries ``ControlStatus.FRAME_REJECTED``, and the part is replaced by what the controller predicts:

* **time** (``CAUSE_TIME``): not finite, or a step from the last accepted time outside
  ``[min_clock_step_s, max_clock_step_s]`` (a repeated or backward time, a jump forward). The frame gets the
  last accepted time plus one period and its motion-capture sample is dropped (its time stamp is suspect
  too). A clock that really stepped (after the frame that jumped, ``clock_settle_frames`` rejected frames in
  a row, each a step within those bounds after the one before) is accepted: from then on
  an offset maps the plant's clock onto the controller's, whose time (and so the trajectory's) stays
  continuous (``CAUSE_CLOCK_RESET``), and the estimator re-initialises from motion capture;
* **IMU** (``CAUSE_IMU``): non-finite, beyond the sensor ranges (the estimator's ``acc_range``,
  ``gyro_range``), or an accelerometer reading beyond ``acc_physical_margin`` times the largest specific force
  the rotors can give (an IMU running away passes through such values before it leaves its range): the last
  good sample for ``imu_hold_s``, then the **coasting** prediction (``coasting``): the specific force of a body
  at rest in its estimated attitude, no rotation, to which the UKF adds its bias estimates and white
  acceleration noise (``EstimatorParams.coast_acc_std``) so that motion capture steers it. Holding one sample
  for long integrates its vibration (or, for an IMU running away, its last plausible value) into metres;
* **motion capture** (``CAUSE_MOCAP``): a non-finite time, position or quaternion, a quaternion norm more than
  ``quat_norm_tol`` from 1, a sample taken after the frame. UKF only: a sample repeating the pose of the one
  before exactly, the ``mocap_frozen_samples``-th time in a row (``CAUSE_MOCAP_FROZEN``: a real motion
  capture's noise never repeats; a frozen one re-sends its last pose with fresh stamps); a **jump against the
  IMU's prediction** (``CAUSE_MOCAP_JUMP``): the innovation (sample minus estimate) moved from the running
  mean of the accepted samples' (about 5) by more than ``pos_jump_m + mocap_drift_mps2 tau² / 2`` (``tau`` the
  time since the last accepted sample: the drift an IMU prediction can have gathered), and every later sample
  offset as that one was (within ``pos_jump_m``, and nearer to it than to the prediction) is the same jump,
  rejected however long it lasts (a marker swap, an offset marker), until
  samples agree with the prediction again. Never flown into: without motion capture the UKF predicts on the
  IMU (flagged degraded), and after ``dropout_reinit_s`` re-anchors on the first samples that agree with the
  prediction. After the IMU coasted the prediction is void: the jump check waits for the next accepted
  sample (and after a blackout the re-initialisation takes its velocity from two samples). The sample is
  dropped: the UKF runs its prediction for that period;
* **bypass state** (``CAUSE_STATE``): non-finite, ``R_WB`` not a proper rotation (``|R^T R - I|`` or
  ``|det R - 1|`` beyond ``rotation_tol``), or (``CAUSE_STATE_JUMP``) a position or velocity jump from the
  last accepted state beyond ``pos_jump_m + max_speed_mps tau`` or ``vel_jump_mps + max_accel_mps2 tau``
  (``tau`` the time since it). With no state to act on, the controller holds its last safe command (the one
  computed from the last good state: in flight a hover-like command) and updates no stateful block, flagged
  ``ESTIMATE_DEGRADED`` (the logged estimate is the last accepted pose, held still). After
  ``bypass_hold_timeout_s`` without an accepted state every period is also flagged ``CAUSE_HOLD_TIMEOUT``: the
  command stays held (there is nothing better to fly on without a state; a 1 s loss drifts about 0.3 m in
  hover) but never silently; the jump checks, whose bounds have grown past use, give way to a consistency
  check: a state is accepted, and the controller resumes, once the positions of consecutive valid states over
  ``bypass_resume_window_s`` moved as their velocities say (within ``pos_jump_m``);
* **bypass velocity against its positions** (``CAUSE_STATE_VELOCITY``): the velocities of the states that
  passed the position check, integrated (trapezoids) over the last ``velocity_window_s`` (a window sliding by
  one period), must move the position as it moved, within ``velocity_tol_m``. Where they do not, the velocity
  carries an offset of its own (a bias of the bypass state's velocity, which the jump checks let through once
  their bound has grown past it: a 3 m/s offset after 50 ms, and a controller that believes it flies away by
  metres). The offset over the window, ``(integral - position change) / window``, is subtracted from the
  velocity in every period in which the window disagrees, each such frame flagged; a constant offset is
  removed exactly one window after it began. The check starts afresh after a loss of the state (hold timeout);
* **bypass position drifting** (``CAUSE_STATE_DRIFT``; SPEC §4.5's supervision, issue 26): position and
  velocity alone cannot say which of the two is wrong when they disagree, so the IMU votes: the velocity's change
  over the window is held against the IMU's acceleration (``R_WB acc_B - g e3``) integrated over it. Beyond
  ``velocity_vote_mps`` the velocity jumped (the offset above is subtracted); within it the velocity moved as
  the vehicle did and the *position* drifts (the vote is taken once, when the window starts to disagree: the
  onset is what tells the two apart; a velocity blamed stays blamed while the window disagrees). From then on
  the position is replaced by the position one window before the disagreement, moved on as the velocities say
  (trapezoids), each frame flagged, until a received position
  agrees with that prediction again (within ``velocity_tol_m``; the velocity check then starts afresh). The jump
  check is off while it drifts (a drift leaves it behind slowly, and would otherwise hold the command). A
  coasting IMU gives no vote (the velocity is then blamed, as before). A drift slower than the velocity check's
  own resolution (``velocity_tol_m / velocity_window_s``, 0.15 m/s) is not seen;
* **rotor speeds** (``CAUSE_ROTOR``): a non-finite speed or one beyond the vehicle's limits by more than
  ``rotor_margin`` of the larger limit: the wrench observer takes the last command for that period.

**The real interval.** Every frame closes an interval ``dt_s`` (the state's field): the checked time minus the
previous checked time, so within ``[min_clock_step_s, max_clock_step_s]``, or the configured period for a
frame whose time was rejected. The controller's blocks (observer, admittance, pose) integrate over it, so a
real loop's jitter is integrated as it happened (the UKF takes its own interval from the same times). An
interval within ``DT_SNAP_S`` (1 ns) of the configured period is taken as the period itself: a simulator's
evenly spaced frames (``k dt``, whose differences wander by rounding) replay bit for bit.

**Blind, and the failsafe** (UKF; SPEC §4.5's supervision, issue 26). While the IMU coasts and no
motion-capture sample was accepted for ``blind_mocap_s``, the controller is *blind*: it holds the last safe
command (computed from the last good estimate: in hover a hover command) and updates no stateful block, as for
a rejected bypass state. The failsafe engages (``CAUSE_FAILSAFE`` on every period from then on,
``ControlStatus.FAILSAFE``; latched until the controller is reset) when the IMU has been rejected for longer than
``failsafe_blind_s`` (a blackout of every input, or of the IMU alone, longer than the 0.3 s the issue asks to
be ridden through) or no motion-capture sample was accepted for ``failsafe_mocap_s``. It belongs here, in the
controller, because in simulation and on a link that drops there is nobody to tell it what to do: the fly node's
director (:mod:`omnirotor.fly.director`) has its own land mode, from the ground height recorded at arming, for a
failsafe it decides; this one needs nothing from outside. It replaces the EE reference
(:func:`failsafe_reference`, called by the composer after the trajectory's sample): **hold** the body's pose
where it engaged (the estimate then) for ``failsafe_hold_s`` of good IMU (while blind the command is held
anyway), then **descend** at ``land_speed_mps`` with that attitude, only while within ``land_radius_m`` of that
point horizontally (a vehicle pushed away while blind first flies back), until **touchdown**: the estimate
``touchdown_m`` above the descending reference (the ground holds it up), after which the rotors get 0 Hz
(``FS_LANDED``). The motion-capture jump check is off during the failsafe: landing, motion capture is the best
truth there is. Shown by ``tests/test_sustained_faults.py``: a 0.5 s or 2 s blackout and an accelerometer
running away land within a few centimetres of where the fault began.

Re-initialisation (UKF): after a clock reset, after the IMU coasted with no motion capture, or when no
motion-capture sample was accepted for ``dropout_reinit_s``, the estimator's pose is taken from the next two
consecutive valid motion-capture samples that agree with each other and pass the jump check (``CAUSE_REINIT``
in the period it happens; :func:`ukf_reinit <omnirotor.control._estimator_kernels.ukf_reinit>`), so that a run
recovers instead of staying degraded.

Shapes (frame length, rotor count) are checked in Python at the API boundary,
:meth:`InteractionController.step <omnirotor.control.controller.InteractionController.step>`.

A clean frame is copied unchanged (its time offset is exactly 0): supervision does not change a clean run's
numbers (``tests/test_controller_reference.py``: none of the checks above fires on the recorded runs, the
corrupted one included, so they replay bit for bit).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from omnirotor._jit import jit, jit_entry
from omnirotor.blocks import register, state_array
from omnirotor.config import check_finite, check_positive
from omnirotor.control import _estimator_kernels as _ek
from omnirotor.errors import InputError
from omnirotor.frame_kernels import clear_mocap, copy_head, copy_state, state_finite
from omnirotor.messages import ESTIMATE_DTYPE, FRAME_HEAD_DTYPE, frame_dtype

__all__ = [
    "SupervisorParams",
    "FrameSupervisor",
    "STATE_DTYPE",
    "CAUSES",
    "CAUSE_TIME",
    "CAUSE_IMU",
    "CAUSE_MOCAP",
    "CAUSE_MOCAP_JUMP",
    "CAUSE_STATE",
    "CAUSE_STATE_JUMP",
    "CAUSE_ROTOR",
    "CAUSE_HOLD_TIMEOUT",
    "CAUSE_CLOCK_RESET",
    "CAUSE_REINIT",
    "CAUSE_STATE_VELOCITY",
    "CAUSE_MOCAP_FROZEN",
    "CAUSE_FAILSAFE",
    "CAUSE_STATE_DRIFT",
    "FS_OFF",
    "FS_HOLD",
    "FS_DESCEND",
    "FS_LANDED",
    "failsafe_reference",
    "REJECTING",
    "supervise",
    "reset_supervisor",
    "causes_of",
]

CAUSE_TIME = 1
"""The frame's time was not finite, not increasing, or jumped forward."""
CAUSE_IMU = 2
"""The IMU sample was not finite or beyond the sensor ranges."""
CAUSE_MOCAP = 4
"""The motion-capture sample was not finite, its quaternion not of unit norm, or taken after the frame."""
CAUSE_MOCAP_JUMP = 8
"""The motion-capture position jumped away from the estimate."""
CAUSE_STATE = 16
"""The bypass state was not finite or its attitude not a proper rotation."""
CAUSE_STATE_JUMP = 32
"""The bypass state's position or velocity jumped."""
CAUSE_ROTOR = 64
"""A measured rotor speed was not finite or beyond the limits plus the margin."""
CAUSE_HOLD_TIMEOUT = 128
"""The bypass prediction has run for longer than the hold timeout: it is held still."""
CAUSE_CLOCK_RESET = 256
"""The plant's clock stepped and was accepted: an offset now maps it onto the controller's time."""
CAUSE_REINIT = 512
"""The estimator re-initialised its pose from motion capture (after a clock reset or a long dropout)."""
CAUSE_STATE_VELOCITY = 1024
"""The bypass velocity disagrees with its positions over the window: its offset is subtracted."""
CAUSE_MOCAP_FROZEN = 2048
"""The motion-capture sample repeats the last one exactly (a frozen motion capture with fresh stamps)."""
CAUSE_FAILSAFE = 4096
"""The failsafe holds and then lands the vehicle (blind too long, or no motion capture for too long)."""
CAUSE_STATE_DRIFT = 8192
"""The bypass position drifts from what its velocity and the IMU say: replaced by the velocity's integral."""

CAUSES = (
    ("time", CAUSE_TIME),
    ("imu", CAUSE_IMU),
    ("mocap", CAUSE_MOCAP),
    ("mocap_jump", CAUSE_MOCAP_JUMP),
    ("state", CAUSE_STATE),
    ("state_jump", CAUSE_STATE_JUMP),
    ("rotor", CAUSE_ROTOR),
    ("hold_timeout", CAUSE_HOLD_TIMEOUT),
    ("clock_reset", CAUSE_CLOCK_RESET),
    ("reinit", CAUSE_REINIT),
    ("state_velocity", CAUSE_STATE_VELOCITY),
    ("mocap_frozen", CAUSE_MOCAP_FROZEN),
    ("failsafe", CAUSE_FAILSAFE),
    ("state_drift", CAUSE_STATE_DRIFT),
)
"""Name and bit of every cause, in bit order (``counts`` has one entry per cause, in this order)."""
N_CAUSES = len(CAUSES)

REJECTING = (
    CAUSE_TIME
    | CAUSE_IMU
    | CAUSE_MOCAP
    | CAUSE_MOCAP_JUMP
    | CAUSE_STATE
    | CAUSE_STATE_JUMP
    | CAUSE_ROTOR
    | CAUSE_STATE_VELOCITY
    | CAUSE_MOCAP_FROZEN
    | CAUSE_STATE_DRIFT
)
"""The causes that reject a part of the frame (``ControlStatus.FRAME_REJECTED``); the others only inform."""
INVALID_VALUE = CAUSE_IMU | CAUSE_MOCAP | CAUSE_STATE | CAUSE_ROTOR
"""The causes that are a non-finite or out-of-range value (also ``ControlStatus.NONFINITE_INPUT``)."""

# What the estimator should do after supervision (the return value's upper bits, below the cause bits).
ACT_REINIT = 1 << 20
"""Return flag of :func:`supervise`: re-initialise the UKF's pose from ``clean``'s motion-capture sample."""

FS_OFF, FS_HOLD, FS_DESCEND, FS_LANDED = 0, 1, 2, 3
"""The failsafe's modes (``fs_mode``): off; holding the pose where it began; descending; landed (rotors off)."""


@dataclasses.dataclass(frozen=True)
class SupervisorParams:
    """Limits of the frame supervision (module docstring); the ``[supervisor]`` section of the controller TOML.

    Attributes:
        rotor_margin: a measured rotor speed may exceed the vehicle's limits by this fraction of the larger
            limit's magnitude (rotor overshoot, speed-sensor noise) before it is rejected.
        min_clock_step_s: the shortest accepted step of the frame time [s] (a tenth of a 1 kHz period: a
            repeated time stamp is rejected even when arithmetic left it a rounding above the last one).
        max_clock_step_s: the longest accepted step of the frame time [s] (50 periods at 1 kHz).
        clock_settle_frames: rejected frames in a row after the one that jumped, each a normal step after the
            one before, after which the plant's clock is taken as having stepped (and the offset re-anchored).
        pos_jump_m: position jump accepted on top of the speed bound [m] (motion-capture noise, latency).
        max_speed_mps: speed bound used for the position-jump checks [m/s].
        vel_jump_mps: velocity jump accepted on top of the acceleration bound (bypass state) [m/s].
        max_accel_mps2: acceleration bound used for the velocity-jump check [m/s²].
        rotation_tol: largest entry of ``R^T R - I`` and ``|det R - 1|`` of an accepted attitude matrix.
        quat_norm_tol: largest ``| |q| - 1 |`` of an accepted motion-capture quaternion.
        dropout_reinit_s: time without an accepted motion-capture sample after which the UKF re-initialises
            its pose from the next good samples [s].
        bypass_hold_timeout_s: time without an accepted bypass state after which the hold is flagged
            ``CAUSE_HOLD_TIMEOUT`` and the jump checks give way to the resume check [s].
        bypass_resume_window_s: after the hold timeout, a state is accepted once the position has moved, over
            this long of consecutive valid states, as their velocity says (within ``pos_jump_m``) [s].
        velocity_window_s: window over which the bypass velocities are integrated and compared with the
            position change [s].
        velocity_tol_m: largest accepted difference between the two over one window [m]; a velocity offset
            larger than ``velocity_tol_m / velocity_window_s`` (0.15 m/s) is found and removed.
        velocity_vote_mps: the third vote, when the two disagree: the velocity's change over the window against
            the IMU's acceleration integrated over it [m/s]; within this, the velocity is believed and the
            position drifts (``CAUSE_STATE_DRIFT``), beyond it the velocity jumped (``CAUSE_STATE_VELOCITY``).
        acc_physical_margin: an accelerometer reading beyond this many times the largest specific force the
            rotors can give (all at full speed, aligned: ``n c_f omega_max² / m``) is rejected as implausible (an
            IMU running away passes through such values before it leaves the sensor's range); 0: only the range.
        mocap_frozen_samples: a motion-capture sample that repeats the pose of the one before exactly, the
            this-many-th time in a row, is rejected as frozen (``CAUSE_MOCAP_FROZEN``: a real motion capture's
            noise never repeats; a frozen one re-sends its last pose with fresh stamps).
        imu_hold_s: a rejected IMU sample is replaced by the last good one for this long after it; after that
            by the coasting prediction (no acceleration, no rotation) [s].
        blind_mocap_s: the IMU coasting and no motion-capture sample accepted for this long, the controller is
            *blind*: it holds the last safe command (nothing to fly on) [s].
        mocap_drift_mps2: the acceleration error the IMU prediction may have accumulated since the last
            accepted motion-capture sample, for the jump check ``pos_jump_m + mocap_drift_mps2 tau² / 2`` [m/s²].
        failsafe: hold and then land when blind or without motion capture for too long (UKF).
        failsafe_blind_s: the IMU rejected for longer than this starts the failsafe [s] (a blackout of up to
            0.3 s is ridden through).
        failsafe_mocap_s: no motion-capture sample accepted for longer than this starts the failsafe [s].
        failsafe_hold_s: the failsafe holds the pose where it began this long (counted while the IMU is
            good) before it descends [s].
        land_speed_mps: the failsafe's descent speed [m/s].
        touchdown_m: the descent is over (touchdown: rotors off) once the estimate is this far above the
            landing reference [m].
        land_radius_m: the failsafe descends only while the estimate is within this of the hold point,
            horizontally (it first flies back there) [m].
    """

    rotor_margin: float = 0.1
    min_clock_step_s: float = 1e-4
    max_clock_step_s: float = 0.05
    clock_settle_frames: int = 5
    pos_jump_m: float = 0.05
    max_speed_mps: float = 5.0
    vel_jump_mps: float = 0.5
    max_accel_mps2: float = 50.0
    rotation_tol: float = 0.01
    quat_norm_tol: float = 0.1
    dropout_reinit_s: float = 0.5
    bypass_hold_timeout_s: float = 0.5
    bypass_resume_window_s: float = 0.05
    velocity_window_s: float = 0.05
    velocity_tol_m: float = 0.0075
    velocity_vote_mps: float = 0.075
    acc_physical_margin: float = 1.5
    imu_hold_s: float = 0.005
    mocap_frozen_samples: int = 3
    blind_mocap_s: float = 0.05
    mocap_drift_mps2: float = 0.5
    failsafe: bool = True
    failsafe_blind_s: float = 0.35
    failsafe_mocap_s: float = 5.0
    failsafe_hold_s: float = 1.0
    land_speed_mps: float = 0.3
    touchdown_m: float = 0.15
    land_radius_m: float = 0.2

    def __post_init__(self) -> None:
        for name in (
            "rotor_margin",
            "min_clock_step_s",
            "max_clock_step_s",
            "pos_jump_m",
            "max_speed_mps",
            "vel_jump_mps",
            "max_accel_mps2",
            "rotation_tol",
            "quat_norm_tol",
            "dropout_reinit_s",
            "bypass_hold_timeout_s",
            "bypass_resume_window_s",
            "velocity_window_s",
            "velocity_tol_m",
            "velocity_vote_mps",
            "imu_hold_s",
            "blind_mocap_s",
            "mocap_drift_mps2",
            "failsafe_blind_s",
            "failsafe_mocap_s",
            "failsafe_hold_s",
            "land_speed_mps",
            "touchdown_m",
            "land_radius_m",
        ):
            check_positive(f"supervisor {name}", getattr(self, name))
        n = self.clock_settle_frames
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise InputError(f"supervisor clock_settle_frames must be an integer >= 1, got {n!r}")
        check_finite("supervisor acc_physical_margin", self.acc_physical_margin)
        if self.acc_physical_margin < 0:
            raise InputError(f"supervisor acc_physical_margin must be >= 0, got {self.acc_physical_margin}")
        n = self.mocap_frozen_samples
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise InputError(f"supervisor mocap_frozen_samples must be an integer >= 1, got {n!r}")
        if not isinstance(self.failsafe, bool):
            raise InputError(f"supervisor failsafe must be true or false, got {self.failsafe!r}")


_F8, _I8 = np.float64, np.int64
DT_SNAP_S = 1e-9
"""An interval within this of the configured period is taken as the period itself [s] (module docstring)."""
VEL_RING = 256
"""Length of the ring of states the velocity check keeps (a window of at most 255 periods)."""
LOG_FIELDS = (("frame_reject", ("cause",)),)
"""What the controller's log records of the supervision: this frame's cause bits (0: a clean frame)."""

STATE_DTYPE = np.dtype(
    [
        # outputs
        ("clean", FRAME_HEAD_DTYPE),  # the checked frame without its rotor speeds (what the estimator reads)
        ("cause", _I8),  # CAUSE_* bits of this frame
        ("dt_s", _F8),  # the interval this frame closes, the blocks integrate over it (module docstring) [s]
        ("counts", _I8, N_CAUSES),  # frames with each cause (CAUSES order)
        ("n_rejected", _I8),  # frames with a rejecting cause
        ("n_nonfinite", _F8),  # frames with a non-finite or out-of-range value (an INVALID_VALUE cause)
        # parameters
        ("dt_nom", _F8),  # the control period [s]
        ("acc_range", _F8),  # [m/s²]
        ("gyro_range", _F8),  # [rad/s]
        ("rotor_lo_hz", _F8),  # the rotor limits with the margin [Hz]
        ("rotor_hi_hz", _F8),
        ("min_step_s", _F8),
        ("max_step_s", _F8),
        ("settle", _I8),
        ("pos_jump_m", _F8),
        ("max_speed_mps", _F8),
        ("vel_jump_mps", _F8),
        ("max_accel_mps2", _F8),
        ("rotation_tol", _F8),
        ("quat_norm_tol", _F8),
        ("dropout_reinit_s", _F8),
        ("hold_timeout_s", _F8),
        ("check_state", _I8),  # 1: the estimator reads the bypass state (check and predict it)
        ("check_mocap", _I8),  # 1: the estimator reads motion capture (jump check, re-init)
        # state
        ("t_last", _F8),  # the controller's time of the last frame [s]
        ("t_raw_last", _F8),  # the plant's time of the last frame with a finite time [s]
        ("offset_s", _F8),  # controller time = plant time + offset [s]
        ("n_consistent", _I8),  # rejected frames in a row, each a normal step after the one before
        ("imu_last", _F8, 6),  # the last good IMU sample: acc_B, gyro_B
        ("t_mocap_ok", _F8),  # controller time of the last accepted motion-capture sample [s]
        ("reinit", _I8),  # 1: re-initialise from the next good samples
        ("prev_ok", _I8),  # 1: prev_p_W holds the last valid sample (re-init candidate)
        ("prev_p_W", _F8, 3),
        ("prev_t", _F8),
        ("state_last", ESTIMATE_DTYPE),  # the last accepted bypass state
        ("t_state_ok", _F8),  # its controller time [s]
        ("resume_ok", _I8),  # 1: resume_state holds a valid state after the hold timeout (resume candidate)
        ("resume_p_W", _F8, 3),  # its position [m] ...
        ("resume_v_W", _F8, 3),  # ... and velocity [m/s]
        ("resume_t", _F8),  # its controller time [s]
        ("resume_window_s", _F8),
        ("vel_tol_m", _F8),
        ("vel_n", _I8),  # states per window (velocity_window_s / dt, at most VEL_RING - 1)
        ("vel_k", _I8),  # states entered into the ring since the check (re)started
        ("vel_int_W", _F8, 3),  # the running integral of the received velocities [m]
        ("vel_prev_W", _F8, 3),  # the last received velocity integrated [m/s]
        ("vel_t_prev", _F8),  # its controller time [s]
        ("vel_ring_t", _F8, VEL_RING),  # the last states' controller times [s] ...
        ("vel_ring_p_W", _F8, (VEL_RING, 3)),  # ... positions [m] ...
        ("vel_ring_int_W", _F8, (VEL_RING, 3)),  # ... and velocity integrals [m]
        ("vel_offset_W", _F8, 3),  # the velocity offset subtracted this frame (0: none) [m/s]
        ("vel_ring_v_W", _F8, (VEL_RING, 3)),  # ... the velocities received [m/s] ...
        ("vel_ring_ia_W", _F8, (VEL_RING, 3)),  # ... and the IMU's acceleration integrals [m/s]
        ("acc_int_W", _F8, 3),  # the running integral of the IMU's acceleration (world, gravity removed) [m/s]
        ("acc_prev_W", _F8, 3),  # the last IMU acceleration integrated [m/s²]
        ("vote_mps", _F8),  # the third vote's tolerance on a window's velocity change [m/s]
        ("drift_on", _I8),  # 1: the position drifts; it is replaced by the velocity's integral
        ("vel_blamed", _I8),  # 1: the vote blamed the velocity: its offset is subtracted while the window disagrees
        # sustained faults (issue 26): IMU coasting, motion-capture jumps and freezes, the failsafe
        ("g", _F8),  # gravity [m/s²] (the coasting IMU sample)
        ("imu_hold_s", _F8),
        ("t_imu_ok", _F8),  # controller time of the last accepted IMU sample [s]
        ("blind_mocap_s", _F8),
        ("blind", _I8),  # 1: the IMU coasts and no motion capture came since: the last safe command is held
        ("coasting", _I8),  # 1: this frame's IMU sample is the coasting prediction
        ("void", _I8),  # 1: the IMU coasted: the prediction is void until motion capture re-anchors it
        ("reinit_v_W", _F8, 3),  # the velocity a re-initialisation takes (NaN: keep the estimator's) [m/s]
        ("drift_mps2", _F8),
        ("innov_ok_W", _F8, 3),  # running mean of motion capture minus estimate of the accepted samples [m]
        ("jump_on", _I8),  # 1: the samples are offset by jump_W from the prediction (rejected)
        ("jump_W", _F8, 3),  # the offset of the last jumped sample [m]
        ("mocap_seen", _I8),
        ("n_same", _I8),  # samples in a row that repeated the one before exactly
        ("frozen_n", _I8),  # 1: last_p_W, last_q_WB hold the last well-formed sample received
        ("last_p_W", _F8, 3),
        ("last_q_WB", _F8, 4),
        ("fs_on", _I8),  # 1: the failsafe is armed (parameters)
        ("fs_blind_s", _F8),
        ("fs_mocap_s", _F8),
        ("fs_hold_s", _F8),
        ("land_speed_mps", _F8),
        ("touchdown_m", _F8),
        ("land_radius_m", _F8),
        ("fs_mode", _I8),  # FS_* (FS_OFF: not engaged)
        ("fs_cause", _I8),  # the causes of the frame that engaged it
        ("fs_t", _F8),  # controller time it engaged [s]
        ("fs_held_s", _F8),  # time held with a good IMU [s]
        ("fs_depth_m", _F8),  # descended so far [m]
        ("fs_p_W", _F8, 3),  # the body's position where it engaged [m] ...
        ("fs_R_WB", _F8, (3, 3)),  # ... and its attitude
    ]
)
"""The supervisor's record: outputs, parameters and state, by name (a field of the controller's state)."""


def reset_supervisor(
    state: np.ndarray,
    params: SupervisorParams,
    frame: np.ndarray,
    *,
    dt: float,
    acc_range: float,
    gyro_range: float,
    omega_min_hz: float,
    omega_max_hz: float,
    check_state: bool,
    check_mocap: bool,
    gravity: float = 9.81,
    acc_physical: float = 0.0,
) -> None:
    """Set the parameters and start from the reset frame (its record); counters cleared.

    Args:
        state: the supervisor's ``(1,)`` record array (:data:`STATE_DTYPE`), e.g. ``controller.state["supervisor"]``.
        params: the limits.
        frame: the reset frame, a ``(1,)`` frame record (:func:`omnirotor.messages.frame_dtype`).
        dt: control period [s].
        acc_range: accelerometer full scale [m/s²].
        gyro_range: gyroscope full scale [rad/s].
        omega_min_hz: the vehicle's lower rotor-speed limit [Hz].
        omega_max_hz: its upper limit [Hz].
        check_state: the estimator reads the bypass state.
        check_mocap: the estimator reads motion capture.
        gravity: [m/s²] (the coasting IMU sample).
        acc_physical: the largest specific force the rotors can give [m/s²] (0: unknown, the range alone).
    """
    state[:] = np.zeros(1, STATE_DTYPE)
    rec = state[0]
    margin = params.rotor_margin * max(abs(omega_min_hz), abs(omega_max_hz))
    rec["dt_nom"] = dt
    rec["acc_range"], rec["gyro_range"] = acc_range, gyro_range
    if acc_physical > 0.0 and params.acc_physical_margin > 0.0:
        rec["acc_range"] = min(acc_range, params.acc_physical_margin * acc_physical)
    rec["rotor_lo_hz"], rec["rotor_hi_hz"] = omega_min_hz - margin, omega_max_hz + margin
    rec["min_step_s"], rec["max_step_s"] = params.min_clock_step_s, params.max_clock_step_s
    rec["settle"] = params.clock_settle_frames
    rec["pos_jump_m"], rec["max_speed_mps"] = params.pos_jump_m, params.max_speed_mps
    rec["vel_jump_mps"], rec["max_accel_mps2"] = params.vel_jump_mps, params.max_accel_mps2
    rec["rotation_tol"], rec["quat_norm_tol"] = params.rotation_tol, params.quat_norm_tol
    rec["dropout_reinit_s"], rec["hold_timeout_s"] = params.dropout_reinit_s, params.bypass_hold_timeout_s
    rec["resume_window_s"] = params.bypass_resume_window_s
    rec["vel_tol_m"] = params.velocity_tol_m
    rec["vel_n"] = min(max(1, round(params.velocity_window_s / dt)), VEL_RING - 1)
    rec["vote_mps"] = params.velocity_vote_mps
    rec["check_state"], rec["check_mocap"] = int(check_state), int(check_mocap)
    rec["blind_mocap_s"] = params.blind_mocap_s
    rec["frozen_n"] = params.mocap_frozen_samples
    rec["g"], rec["imu_hold_s"], rec["drift_mps2"] = gravity, params.imu_hold_s, params.mocap_drift_mps2
    rec["fs_on"] = int(params.failsafe and check_mocap)
    rec["fs_blind_s"], rec["fs_mocap_s"] = params.failsafe_blind_s, params.failsafe_mocap_s
    rec["fs_hold_s"], rec["land_speed_mps"] = params.failsafe_hold_s, params.land_speed_mps
    rec["touchdown_m"], rec["land_radius_m"] = params.touchdown_m, params.land_radius_m
    f = frame[0]
    t = float(f["t"])
    rec["t_last"] = rec["t_raw_last"] = rec["t_mocap_ok"] = rec["t_state_ok"] = rec["t_imu_ok"] = t
    for name in FRAME_HEAD_DTYPE.names:
        rec["clean"][name] = f[name]
    imu = np.r_[f["imu"]["acc_B"], f["imu"]["gyro_B"]]
    rec["imu_last"] = imu if np.all(np.isfinite(imu)) else 0.0
    st = f["state"]
    if st["valid"] != 0.0 and all(np.all(np.isfinite(st[name])) for name in ESTIMATE_DTYPE.names):
        rec["state_last"] = st


def causes_of(cause: int) -> list[str]:
    """The names of the causes in ``cause`` (bits), in bit order."""
    return [name for name, bit in CAUSES if cause & bit]


@jit
def _count(sv, cause: int) -> None:
    for i in range(sv.counts.shape[0]):
        if cause & (1 << i):
            sv.counts[i] += 1
    if cause & REJECTING:
        sv.n_rejected += 1
    if cause & INVALID_VALUE:
        sv.n_nonfinite += 1


@jit
def _check_time(sv, frame, clean) -> int:
    """The time check (module docstring); writes the controller's time into ``clean``; the cause bits."""
    t_raw = frame.t
    tc = t_raw + sv.offset_s
    d = tc - sv.t_last
    cause = 0
    if sv.min_step_s <= d <= sv.max_step_s:  # False for NaN
        sv.n_consistent = 0
    else:
        cause = CAUSE_TIME
        tc = sv.t_last + sv.dt_nom
        d_raw = t_raw - sv.t_raw_last
        if sv.min_step_s <= d_raw <= sv.max_step_s:
            sv.n_consistent += 1
        else:
            sv.n_consistent = 0
        if sv.n_consistent >= sv.settle:  # the plant's clock stepped: follow it from here, continuously
            sv.offset_s = tc - t_raw
            sv.n_consistent = 0
            sv.reinit = sv.check_mocap
            cause |= CAUSE_CLOCK_RESET
    if math.isfinite(t_raw):
        sv.t_raw_last = t_raw
    d = tc - sv.t_last
    sv.dt_s = sv.dt_nom if abs(d - sv.dt_nom) < DT_SNAP_S else d
    sv.t_last = tc
    clean.t = tc
    return cause


@jit
def _check_imu(sv, clean, estimate) -> int:
    """The IMU check; a rejected sample is replaced by the last good one, then by the coasting prediction.

    After ``imu_hold_s`` the prediction is the specific force of a body at rest in its estimated attitude, no
    rotation (the estimator adds its biases back).
    """
    ok = True
    acc, gyro = clean.imu.acc_B, clean.imu.gyro_B
    for i in range(3):
        a, g = acc[i], gyro[i]
        if not (abs(a) <= sv.acc_range and abs(g) <= sv.gyro_range):  # False for NaN
            ok = False
    if ok:
        for i in range(3):
            sv.imu_last[i] = acc[i]
            sv.imu_last[3 + i] = gyro[i]
        sv.t_imu_ok = clean.t
        sv.coasting = 0
        return 0
    if clean.t - sv.t_imu_ok <= sv.imu_hold_s:
        for i in range(3):
            acc[i] = sv.imu_last[i]
            gyro[i] = sv.imu_last[3 + i]
        return CAUSE_IMU
    sv.coasting = 1
    if sv.void == 0:  # coasting starts: the prediction no longer says where the vehicle is
        sv.void = 1
        if clean.t - sv.t_mocap_ok > sv.imu_hold_s:  # nor does motion capture: re-anchor when it returns
            sv.reinit = sv.check_mocap
    R = estimate.R_WB
    for i in range(3):
        acc[i] = R[2, i] * sv.g  # R^T (0, 0, g)
        gyro[i] = 0.0
    if not (math.isfinite(acc[0]) and math.isfinite(acc[1]) and math.isfinite(acc[2])):
        for i in range(3):
            acc[i] = sv.imu_last[i]
    return CAUSE_IMU


@jit
def _dist3(x, y) -> float:
    d0, d1, d2 = x[0] - y[0], x[1] - y[1], x[2] - y[2]
    return math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)


@jit
def _frozen(sv, m) -> bool:
    """Whether the well-formed sample ``m`` is the ``frozen_n``-th in a row to repeat the same pose exactly."""
    same = sv.mocap_seen != 0
    for i in range(3):
        if m.p_W[i] != sv.last_p_W[i]:
            same = False
        sv.last_p_W[i] = m.p_W[i]
    for i in range(4):
        if m.q_WB[i] != sv.last_q_WB[i]:
            same = False
        sv.last_q_WB[i] = m.q_WB[i]
    sv.mocap_seen = 1
    sv.n_same = sv.n_same + 1 if same else 0
    return sv.n_same >= sv.frozen_n


@jit
def _jumped(sv, p_m, p_est, since: float) -> bool:
    """The jump check against the IMU's prediction (module docstring); remembers the innovation it judged.

    The innovation ``p_m - p_est`` must stay within ``pos_jump_m + drift_mps2 since² / 2`` of the running mean
    of the accepted samples' (over about 5). A sample beyond starts (or continues) a *jump*: later samples
    offset as it is (within ``pos_jump_m``, and nearer to it than to the prediction) are the same jump,
    rejected however long it lasts (a marker swap, a moved origin), until samples agree with the prediction
    again.
    """
    d_ok, d_jump = 0.0, 0.0
    if not (math.isfinite(p_est[0]) and math.isfinite(p_est[1]) and math.isfinite(p_est[2])):
        return False  # nothing to judge against
    for i in range(3):
        r = p_m[i] - p_est[i]
        d_ok += (r - sv.innov_ok_W[i]) ** 2
        d_jump += (r - sv.jump_W[i]) ** 2
    bound = sv.pos_jump_m + 0.5 * sv.drift_mps2 * since * since
    d_ok, d_jump = math.sqrt(d_ok), math.sqrt(d_jump)
    same_jump = sv.jump_on != 0 and d_jump <= sv.pos_jump_m and d_jump < d_ok
    if same_jump or d_ok > bound:
        sv.jump_on = 1
        for i in range(3):
            sv.jump_W[i] = p_m[i] - p_est[i]
        return True
    sv.jump_on = 0
    for i in range(3):  # a running mean (5 samples): one noisy sample does not move the reference far
        sv.innov_ok_W[i] += 0.2 * (p_m[i] - p_est[i] - sv.innov_ok_W[i])
    return False


@jit
def _check_mocap(sv, clean, estimate, time_bad: bool) -> int:
    """The motion-capture checks; a rejected sample is dropped from ``clean``. Cause bits, plus ``ACT_REINIT``."""
    m = clean.mocap
    if m.new == 0.0:
        return 0
    if time_bad:  # its time stamp is as suspect as the frame's
        clear_mocap(m)
        return 0
    tc = clean.t
    mt = m.t + sv.offset_s
    m.t = mt
    valid = _ek.mocap_sample_valid(m.p_W[:], m.q_WB[:], sv.quat_norm_tol)  # [:]: as arrays (one compiled check)
    if not (valid and mt <= tc + 0.5 * sv.dt_nom):  # False for a NaN time
        clear_mocap(m)
        sv.prev_ok = 0
        return CAUSE_MOCAP
    if sv.check_mocap == 0:
        return 0
    if _frozen(sv, m):
        clear_mocap(m)
        sv.prev_ok = 0
        return CAUSE_MOCAP_FROZEN
    since = tc - sv.t_mocap_ok
    if sv.void == 0 and sv.fs_mode == FS_OFF and _jumped(sv, m.p_W, estimate.p_W, since):
        clear_mocap(m)  # not where the IMU's prediction can have drifted since the last accepted sample
        sv.prev_ok = 0
        return CAUSE_MOCAP_JUMP
    if sv.reinit != 0 or since > sv.dropout_reinit_s:
        # Re-initialise from two consecutive samples that agree; the first one waits (not fused).
        t_prev = sv.prev_t
        agree = sv.prev_ok != 0 and _dist3(m.p_W, sv.prev_p_W) <= sv.pos_jump_m + sv.max_speed_mps * (mt - t_prev)
        for i in range(3):
            sv.prev_p_W[i] = m.p_W[i]
        sv.prev_ok = 1
        m.new = 0.0
        if not agree:
            for i in range(3):
                sv.reinit_v_W[i] = m.p_W[i]  # the first candidate, kept for the velocity
            sv.prev_t = mt
            return 0
        for i in range(3):  # after a void prediction, the velocity of the two samples; else the estimator's
            void = sv.void != 0 and mt > t_prev
            sv.reinit_v_W[i] = (m.p_W[i] - sv.reinit_v_W[i]) / (mt - t_prev) if void else math.nan
            sv.innov_ok_W[i] = 0.0
        sv.reinit = 0
        sv.prev_ok = 0
        sv.jump_on = 0
        sv.void = 0
        sv.t_mocap_ok = tc
        return CAUSE_REINIT | ACT_REINIT
    sv.void = 0
    sv.t_mocap_ok = tc
    return 0


@jit
def _proper_rotation(R, tol: float) -> bool:
    """True if the 3 x 3 ``R`` has ``|R^T R - I|`` entries and ``|det R - 1|`` within ``tol``."""
    for i in range(3):
        for j in range(i, 3):
            dot = R[0, i] * R[0, j] + R[1, i] * R[1, j] + R[2, i] * R[2, j]
            if not abs(dot - (1.0 if i == j else 0.0)) <= tol:
                return False
    det = (
        R[0, 0] * (R[1, 1] * R[2, 2] - R[1, 2] * R[2, 1])
        - R[0, 1] * (R[1, 0] * R[2, 2] - R[1, 2] * R[2, 0])
        + R[0, 2] * (R[1, 0] * R[2, 1] - R[1, 1] * R[2, 0])
    )
    return abs(det - 1.0) <= tol


@jit
def _resume_check(sv, s, tc: float) -> int:
    """After the hold timeout: 0 when the position moved as the velocity says over the resume window."""
    rp, rv = sv.resume_p_W, sv.resume_v_W
    if sv.resume_ok == 0:
        for i in range(3):
            rp[i] = s.p_W[i]
            rv[i] = s.v_W[i]
        sv.resume_t = tc
        sv.resume_ok = 1
        return CAUSE_STATE_JUMP
    tau = tc - sv.resume_t
    if tau < sv.resume_window_s:
        return CAUSE_STATE_JUMP
    e2 = 0.0
    for i in range(3):
        e = s.p_W[i] - rp[i] - 0.5 * (s.v_W[i] + rv[i]) * tau
        e2 += e * e
    if math.sqrt(e2) <= sv.pos_jump_m:
        sv.resume_ok = 0
        return 0
    for i in range(3):
        rp[i] = s.p_W[i]
        rv[i] = s.v_W[i]
    sv.resume_t = tc
    return CAUSE_STATE_JUMP


@jit
def _imu_accel_W(sv, clean, R, i: int) -> float:
    """Component ``i`` of the IMU's acceleration in the world frame, gravity removed: ``R acc_B - g e3``."""
    acc = clean.imu.acc_B
    a = R[i, 0] * acc[0] + R[i, 1] * acc[1] + R[i, 2] * acc[2]
    return a - sv.g if i == 2 else a


@jit
def _check_velocity(sv, s, clean, tc: float) -> int:
    """The velocity against the positions, the IMU the third vote (module docstring); fixes the state ``s``.

    A ring of the last ``vel_n`` states holds their times, positions, velocities and the running integrals of
    the received velocities and of the IMU's acceleration, so the window slides by one frame each period and
    an offset is found within one window. When the window disagrees, the velocity's change over it is held
    against the IMU's acceleration integrated over it: the velocity that changed as the IMU says is believed
    and the position drifts (:func:`_drift_position`); otherwise the velocity's offset is subtracted, and keeps
    being subtracted (the velocity stays blamed, the vote is not asked again) while the window disagrees: once
    the offset has lasted a window, the velocity no longer changes, and only the onset told the two apart.
    """
    integral, prev = sv.vel_int_W, sv.vel_prev_W
    ia, aprev = sv.acc_int_W, sv.acc_prev_W
    R = s.R_WB
    if sv.vel_k == 0:
        for i in range(3):
            integral[i], prev[i] = 0.0, s.v_W[i]
            ia[i], aprev[i] = 0.0, _imu_accel_W(sv, clean, R, i)
    else:
        h = 0.5 * (tc - sv.vel_t_prev)
        for i in range(3):
            integral[i] += h * (prev[i] + s.v_W[i])
            prev[i] = s.v_W[i]
            a = _imu_accel_W(sv, clean, R, i)
            ia[i] += h * (aprev[i] + a)
            aprev[i] = a
    sv.vel_t_prev = tc
    size = sv.vel_ring_t.shape[0]
    j = sv.vel_k % size
    sv.vel_ring_t[j] = tc
    for i in range(3):
        sv.vel_ring_p_W[j, i] = s.p_W[i]
        sv.vel_ring_int_W[j, i] = integral[i]
        sv.vel_ring_v_W[j, i] = s.v_W[i]
        sv.vel_ring_ia_W[j, i] = ia[i]
    sv.vel_k += 1
    offset = sv.vel_offset_W
    biased = 0
    o = 0
    if sv.vel_k > sv.vel_n:
        o = (sv.vel_k - 1 - sv.vel_n) % size  # the state one window ago
        window = tc - sv.vel_ring_t[o]
        e2 = 0.0
        for i in range(3):
            offset[i] = (integral[i] - sv.vel_ring_int_W[o, i]) - (s.p_W[i] - sv.vel_ring_p_W[o, i])
            e2 += offset[i] * offset[i]
        if window > 0.0 and math.sqrt(e2) > sv.vel_tol_m:
            biased = 1
            for i in range(3):
                offset[i] /= window
    if biased == 0:
        for i in range(3):
            offset[i] = 0.0
        sv.vel_blamed = 0
        return 0
    if sv.vel_blamed == 0 and sv.coasting == 0:  # the third vote, once (a coasting IMU has none)
        d2 = 0.0
        for i in range(3):
            d = (s.v_W[i] - sv.vel_ring_v_W[o, i]) - (ia[i] - sv.vel_ring_ia_W[o, i])
            d2 += d * d
        if math.sqrt(d2) <= sv.vote_mps:  # the velocity changed as the IMU says: the position drifts
            for i in range(3):
                offset[i] = 0.0
            sv.drift_on = 1
            for i in range(3):  # from the position one window ago, moved as the velocities say
                s.p_W[i] = sv.vel_ring_p_W[o, i] + integral[i] - sv.vel_ring_int_W[o, i]
            return CAUSE_STATE_DRIFT
    sv.vel_blamed = 1  # the velocity jumped: it stays blamed while the window disagrees
    for i in range(3):
        s.v_W[i] -= offset[i]
    return CAUSE_STATE_VELOCITY


@jit
def _drift_position(sv, s, tc: float) -> int:
    """While the position drifts: replace it by the last accepted one moved as the velocity says (trapezoid).

    Until a received position agrees with that prediction again (within ``velocity_tol_m``, the disagreement
    the drift was found by: a drift found goes on beyond it): the drift is over and the velocity check starts
    afresh.
    """
    last = sv.state_last
    h = 0.5 * (tc - sv.t_state_ok)
    e2 = 0.0
    for i in range(3):
        e = s.p_W[i] - (last.p_W[i] + h * (last.v_W[i] + s.v_W[i]))
        e2 += e * e
    if math.sqrt(e2) <= sv.vel_tol_m:
        sv.drift_on = 0
        sv.vel_k = 0
        sv.vel_blamed = 0
        return 0
    for i in range(3):
        s.p_W[i] = last.p_W[i] + h * (last.v_W[i] + s.v_W[i])
    return CAUSE_STATE_DRIFT


@jit
def _check_state(sv, clean, time_bad: bool) -> int:
    """The bypass state's checks; a rejected state is replaced by the prediction (module docstring)."""
    s = clean.state
    if s.valid == 0.0:
        return 0  # missing: the bypass estimator holds its last state, flagged degraded
    tc = clean.t
    tau = tc - sv.t_state_ok
    last = sv.state_last
    cause = 0
    flag = 0  # informs, the state is used (a velocity offset subtracted)
    if not (state_finite(s) and _proper_rotation(s.R_WB, sv.rotation_tol)):
        cause = CAUSE_STATE
        sv.resume_ok = 0
    elif not time_bad and tau > sv.hold_timeout_s:
        cause = _resume_check(sv, s, tc)
        sv.vel_k = 0  # after a loss the velocity check starts afresh
        sv.drift_on = 0
        sv.vel_blamed = 0
    elif not time_bad:
        dp = 0.0
        for i in range(3):
            e = s.p_W[i] - last.p_W[i] - last.v_W[i] * tau
            dp += e * e
        if sv.drift_on != 0:  # the position drifts: its own check, not the jump's (module docstring)
            flag = _drift_position(sv, s, tc)
            if _dist3(s.v_W, last.v_W) > sv.vel_jump_mps + sv.max_accel_mps2 * tau:
                cause = CAUSE_STATE_JUMP
        elif math.sqrt(dp) > sv.pos_jump_m + sv.max_speed_mps * tau:
            cause = CAUSE_STATE_JUMP
        else:
            flag = _check_velocity(sv, s, clean, tc)
            if _dist3(s.v_W, last.v_W) > sv.vel_jump_mps + sv.max_accel_mps2 * tau:
                cause = CAUSE_STATE_JUMP
    if cause == 0 and not time_bad:
        copy_state(s, last)
        sv.t_state_ok = tc
        return flag
    if cause == 0:
        return 0  # a good state in a frame of bad time: used, not kept as the reference
    # The prediction: the last accepted pose, held still.
    if tau > sv.hold_timeout_s:
        cause |= CAUSE_HOLD_TIMEOUT
    for i in range(3):
        s.p_W[i] = last.p_W[i]
        s.v_W[i] = 0.0
        s.a_W[i] = 0.0
        s.omega_B[i] = 0.0
        for j in range(3):
            s.R_WB[i, j] = last.R_WB[i, j]
    return cause


@jit
def _check_rotors(sv, rotor_hz) -> int:
    lo, hi = sv.rotor_lo_hz, sv.rotor_hi_hz
    for i in range(rotor_hz.shape[0]):
        w = rotor_hz[i]
        if not (lo <= w <= hi):  # False for NaN
            return CAUSE_ROTOR
    return 0


@jit
def _failsafe_check(sv, tc: float, estimate, cause: int) -> int:
    """Engage the failsafe (module docstring) when blind or without motion capture for too long; its bit."""
    if sv.fs_mode == FS_OFF:
        if not (tc - sv.t_imu_ok > sv.fs_blind_s or tc - sv.t_mocap_ok > sv.fs_mocap_s):
            return 0
        sv.fs_mode = FS_HOLD
        sv.fs_cause = cause
        sv.fs_t = tc
        sv.fs_held_s = 0.0
        sv.fs_depth_m = 0.0
        for i in range(3):
            sv.fs_p_W[i] = estimate.p_W[i]
            for j in range(3):
                sv.fs_R_WB[i, j] = estimate.R_WB[i, j]
    return CAUSE_FAILSAFE


@jit
def _horizontal(p, q) -> float:
    return math.sqrt((p[0] - q[0]) ** 2 + (p[1] - q[1]) ** 2)


@jit
def failsafe_reference(sv, estimate, p_E_B, dt: float, ref) -> None:
    """The failsafe's EE reference into ``ref`` (a ``REFERENCE_DTYPE`` record) for this period; its mode on.

    Holds the body where the failsafe engaged for ``fs_hold_s`` (counted while the IMU is good: blind, it
    holds), then descends at ``land_speed_mps`` with the attitude it had, while within ``land_radius_m`` of
    that point horizontally; touchdown (``FS_LANDED``: the rotors
    stop) once the estimate is ``touchdown_m`` above the descending reference. Called by the composer after
    the trajectory's sample while ``fs_mode`` is on (SPEC §4.5's supervision; the fly node's director lands
    the same way from its own ground height, :mod:`omnirotor.fly.director`).
    """
    good = sv.clean.t - sv.t_imu_ok <= sv.imu_hold_s
    v = 0.0
    if sv.fs_mode == FS_HOLD and good:
        sv.fs_held_s += dt
        if sv.fs_held_s >= sv.fs_hold_s:
            sv.fs_mode = FS_DESCEND
    elif sv.fs_mode == FS_DESCEND and good and _horizontal(estimate.p_W, sv.fs_p_W) <= sv.land_radius_m:
        sv.fs_depth_m += sv.land_speed_mps * dt
        v = -sv.land_speed_mps
        if estimate.p_W[2] - (sv.fs_p_W[2] - sv.fs_depth_m) > sv.touchdown_m:
            sv.fs_mode = FS_LANDED
    R = sv.fs_R_WB
    for i in range(3):
        ref.p_W[i] = sv.fs_p_W[i] + R[i, 0] * p_E_B[0] + R[i, 1] * p_E_B[1] + R[i, 2] * p_E_B[2]
        ref.v_W[i] = 0.0
        ref.a_W[i] = 0.0
        ref.omega_W[i] = 0.0
        ref.alpha_W[i] = 0.0
        for j in range(3):
            ref.R_WB[i, j] = R[i, j]
    ref.p_W[2] -= sv.fs_depth_m
    ref.v_W[2] = v


@jit
def supervise(sv, frame, estimate) -> int:
    """Check one frame record (module docstring): ``sv.clean`` gets the checked frame, ``sv.cause`` the causes.

    Args:
        sv: the supervisor's record (:data:`STATE_DTYPE`), updated.
        frame: the frame record as received (not modified).
        estimate: the estimate record of the previous period (:data:`~omnirotor.messages.ESTIMATE_DTYPE`),
            the prediction motion capture is checked against.

    Returns:
        The cause bits, plus ``ACT_REINIT`` when the UKF is to re-initialise from ``sv.clean``'s
        motion-capture position and quaternion (which then stays dropped from the normal fusion).
    """
    clean = sv.clean
    copy_head(frame, clean)
    cause = _check_time(sv, frame, clean)
    time_bad = (cause & CAUSE_TIME) != 0
    cause |= _check_imu(sv, clean, estimate)
    cause |= _check_mocap(sv, clean, estimate, time_bad)
    if sv.check_mocap != 0 and clean.t - sv.t_mocap_ok > sv.dropout_reinit_s:
        sv.reinit = 1
    tc = clean.t
    sv.blind = 1 if (tc - sv.t_imu_ok > sv.imu_hold_s and tc - sv.t_mocap_ok > sv.blind_mocap_s) else 0
    if sv.fs_on != 0:
        cause |= _failsafe_check(sv, tc, estimate, cause)
    if sv.check_state != 0:
        cause |= _check_state(sv, clean, time_bad)
    cause |= _check_rotors(sv, frame.rotor_hz)
    code = cause & (ACT_REINIT - 1)
    sv.cause = code
    if code != 0:
        _count(sv, code)
    return cause


@jit
def supervisor_reference(sv, estimate, p_E_B, dt: float, ref) -> None:
    """The supervisor kind's entry ``reference`` (:data:`omnirotor.blocks.KIND_STEPS`): :func:`failsafe_reference`."""
    failsafe_reference(sv, estimate, p_E_B, dt, ref)


@jit_entry
def _supervise_entry(state, frame, estimate) -> int:
    return supervise(state[0], frame[0], estimate[0])


@register("supervisor", "frame-checks")
class FrameSupervisor:
    """The frame supervision of this module as a block of the supervisor kind (SPEC §4.5; module docstring).

    Its record (:data:`STATE_DTYPE`) is a field of the controller's state, whose compiled step calls
    :func:`supervise` (the kind's ``kernel``) first in every period and :func:`failsafe_reference` (its entry
    ``reference``) while the failsafe is on. From Python, :meth:`step` checks one frame as that step does.

    Args:
        vehicle: the vehicle (rotor-speed limits, gravity, the largest specific force its rotors give).
        params: the limits; default :class:`SupervisorParams()`.
        state: optional ``(1,)`` array of :data:`STATE_DTYPE` to keep the state in (the controller's field).
    """

    state_dtype = STATE_DTYPE
    log_fields = LOG_FIELDS
    kernel = supervise
    reference = supervisor_reference

    def __init__(self, vehicle, params: SupervisorParams | None = None, *, state: np.ndarray | None = None):
        self.vehicle = vehicle
        self.params = params if params is not None else SupervisorParams()
        self.state = state_array(STATE_DTYPE, state, "frame supervisor")
        self._estimate = np.zeros(1, ESTIMATE_DTYPE)
        self._frame: np.ndarray | None = None
        self._reset_args: dict | None = None

    def reset(
        self,
        frame: np.ndarray,
        *,
        dt: float,
        acc_range: float,
        gyro_range: float,
        check_state: bool,
        check_mocap: bool,
    ) -> None:
        """Set the parameters and start from the reset frame's record (:func:`reset_supervisor`).

        Args:
            frame: the reset frame, a ``(1,)`` frame record (:func:`omnirotor.messages.frame_dtype`).
            dt: control period [s].
            acc_range: accelerometer full scale [m/s²].
            gyro_range: gyroscope full scale [rad/s].
            check_state: the estimator reads the bypass state (check it).
            check_mocap: the estimator reads motion capture (jump check, re-initialisation, failsafe).
        """
        v = self.vehicle
        reset_supervisor(
            self.state, self.params, frame, dt=dt, acc_range=acc_range, gyro_range=gyro_range,
            omega_min_hz=float(v.omega_min_hz), omega_max_hz=float(v.omega_max_hz), check_state=check_state,
            check_mocap=check_mocap, gravity=v.gravity, acc_physical=v.n_rotors * v.c_f * v.omega_max_hz**2 / v.mass,
        )  # fmt: skip

    def step(self, frame, estimate) -> int:
        """Check one frame against the last period's estimate; the checked frame is ``state["clean"]``.

        Args:
            frame: a :class:`~omnirotor.messages.SensorFrame`.
            estimate: a :class:`~omnirotor.messages.StateEstimate` (the prediction motion capture is checked
                against).

        Returns:
            The cause bits (:data:`CAUSES`) plus ``ACT_REINIT`` (module docstring).
        """
        n = np.shape(frame.rotor_hz)[0]
        if self._frame is None or self._frame.dtype != frame_dtype(n):
            self._frame = np.zeros(1, frame_dtype(n))
        frame.write_record(self._frame)
        e = self._estimate
        e["valid"] = 1.0
        e["p_W"], e["v_W"], e["a_W"], e["omega_B"] = estimate.p_W, estimate.v_W, estimate.a_W, estimate.omega_B
        e["R_WB"] = np.reshape(estimate.R_WB, (1, 3, 3))
        return int(_supervise_entry(self.state, self._frame, e))
