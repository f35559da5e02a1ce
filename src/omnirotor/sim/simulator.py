"""The simulated plant: MuJoCo rigid body and contact, SPEC §7 rotor wrench, sensors (SPEC §2, §1.4, §7).

One :meth:`Simulator.step` is one control period. Time line of a step from t to t + dt:

1. the body is integrated over the period with the acceleration computed at t (MuJoCo semi-implicit Euler,
   ``substeps`` physics steps);
2. the rotor speeds follow the command held over the period (first-order lag, SPEC §1.4);
3. the truth model gives the rotor wrench of the new speeds; it and any external wrench go into
   ``xfrc_applied``; ``mj_forward`` computes contacts and the acceleration at t + dt;
4. the sensors sample the state at t + dt.

So a frame's IMU reading and its ground truth describe the same instant, and a command acts through the
rotor lag only (rotor speeds are states, they cannot jump).

MuJoCo free-joint conventions used here: ``qpos = [p_W, q_WB (wxyz)]``, ``qvel = [v_W, omega_B]``,
``qacc = [p_ddot_W, omega_dot_B]``; the body origin is the CoM.

Assumptions [A] of the plant (all parameters, see :mod:`omnirotor.sim.params`): sensor noise levels and
4 ms motion-capture latency; sliding friction 0.3; soft contacts with a 5 ms time constant, critically
damped (MuJoCo's default impedance, which leaves sub-millimetre penetration at a few newtons); a Ø16 mm
tip on a Ø10 mm rod; collision-enabled propeller disks; rotor lag 25 ms (SPEC §1.4). With ``substeps`` > 1
the rotor wrench is computed once per control period and held (its world direction follows the body).
"""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np

from omnirotor.errors import InputError
from omnirotor.messages import RotorCommand, SensorFrame, StateEstimate
from omnirotor.sim.aero import make_aero
from omnirotor.sim.model import BODY_NAME, EE_ROD_GEOM, EE_SITE, EE_TIP_GEOM, build_mjcf
from omnirotor.sim.params import SimParams
from omnirotor.sim.rotors import RotorBank
from omnirotor.sim.scenes import SCENES, SceneAnchors, default_start_pose, scene_anchors
from omnirotor.sim.sensors import Imu, Mocap, NoiseStream, R9_from_quat, quat_perturb
from omnirotor.so3 import quat_wxyz_from_R
from omnirotor.vehicle import VehicleParams

__all__ = ["Simulator", "GroundTruth"]

_N_STREAMS = 5
"""Independent noise streams spawned from the seed: IMU biases, IMU noise, mocap, rotor speeds, state."""


@dataclasses.dataclass(frozen=True)
class GroundTruth:
    """True state for evaluation only (a controller must never see it).

    Attributes:
        t: time [s].
        p_W: (3,) CoM position [m].
        v_W: (3,) CoM velocity [m/s].
        a_W: (3,) CoM acceleration p_ddot [m/s²] (gravity not included).
        R_WB: (3, 3) attitude.
        omega_B: (3,) angular velocity [rad/s].
        rotor_hz: (n,) rotor speeds [Hz].
        rotor_wrench_B: (6,) true rotor wrench at the CoM, body frame [N, N·m].
        contact_force_W: (3,) force the environment applies on the end-effector (tip and rod) [N].
        contact_moment_W: (3,) moment of those contact forces about the EE tip p_E [N·m].
        in_contact: True when the end-effector touches the environment.
        p_E_W: (3,) EE tip position [m].
        other_contact: True when another part of the vehicle (frame, propeller) touches the environment.
    """

    t: float
    p_W: np.ndarray
    v_W: np.ndarray
    a_W: np.ndarray
    R_WB: np.ndarray
    omega_B: np.ndarray
    rotor_hz: np.ndarray
    rotor_wrench_B: np.ndarray
    contact_force_W: np.ndarray
    contact_moment_W: np.ndarray
    in_contact: bool
    p_E_W: np.ndarray
    other_contact: bool = False


class Simulator:
    """A vehicle in a scene, stepped at the control rate.

    Attributes:
        vehicle: the vehicle.
        params: the simulator parameters.
        scene: the :class:`~omnirotor.sim.scenes.SceneAnchors` of the loaded scene (surface point, outward
            normal, pipe or hole geometry), world frame.
        scene_name: the scene's name.
        model: the ``mujoco.MjModel`` (for rendering).
        data: the ``mujoco.MjData``.
        aero: the truth aerodynamics; ``aero.wrench_B(u_hz2)`` gives the (6,) body wrench.
        rotors: the rotor speed states (:class:`~omnirotor.sim.rotors.RotorBank`).
        imu: the IMU model (its drawn biases: ``imu.acc_bias_B``, ``imu.gyro_bias_B``).
        mocap: the motion-capture model.
        dt: control period [s].

    Args:
        vehicle: the vehicle.
        scene: one of :data:`SCENES`.
        params: simulator parameters (default :class:`SimParams`).
        seed: seed of every noise source (same seed, same run).

    Raises:
        InputError: unknown scene.
    """

    def __init__(
        self, vehicle: VehicleParams, scene: str = "free", params: SimParams | None = None, seed: int = 0
    ) -> None:
        if scene not in SCENES:
            raise InputError(f"unknown scene {scene!r}; scenes: {', '.join(SCENES)}")
        if not isinstance(seed, (int, np.integer)) or seed < 0:
            raise InputError(f"seed must be an integer >= 0, got {seed!r}")
        self.vehicle = vehicle
        self.params = params or SimParams()
        self.seed = int(seed)
        self.scene_name = scene
        self.scene: SceneAnchors = scene_anchors(scene, self.params.scene)
        p = self.params
        self.dt = p.dt
        self.substeps = p.substeps
        xml = build_mjcf(vehicle, scene, p.scene, p.dt / p.substeps)
        self.model = mujoco.MjModel.from_xml_string(xml)
        self.data = mujoco.MjData(self.model)
        m = self.model
        self._body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, BODY_NAME)
        self._ee_site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, EE_SITE)
        robot = np.flatnonzero(m.geom_bodyid == self._body)
        self._robot_geom = np.zeros(m.ngeom, dtype=bool)
        self._robot_geom[robot] = True
        self._ee_geom = np.zeros(m.ngeom, dtype=bool)
        for name in (EE_TIP_GEOM, EE_ROD_GEOM):
            gid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, name)
            if gid >= 0:
                self._ee_geom[gid] = True
        jnt = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, "root")
        self._qp = int(m.jnt_qposadr[jnt])
        self._qv = int(m.jnt_dofadr[jnt])

        self.aero = make_aero(vehicle, p.aero)
        self.rotors = RotorBank(vehicle, p.rotors, p.dt)
        self.imu = Imu(p.sensors, vehicle.gravity)
        self.mocap = Mocap(p.sensors, p.dt)
        self._p_E_B = vehicle.p_E_B_array.copy()
        n = vehicle.n_rotors
        self._n_shape = (n,)
        # Preallocated buffers of the step.
        self._w_B = np.zeros(6)
        self._qn = [1.0, 0.0, 0.0, 0.0]
        self._p_E_B_list = self._p_E_B.tolist()
        self._ext_f = [0.0, 0.0, 0.0]
        self._ext_m = [0.0, 0.0, 0.0]
        self._ext_at_ee = False
        self._provide_state = p.provide_state
        self._has_ext = False
        self._cf6 = np.zeros(6)
        self._k = 0
        self._truth: GroundTruth | None = None
        self._rotor_noise: NoiseStream | None = None
        self._state_noise: NoiseStream | None = None
        s = p.sensors
        self._state_exact = (
            s.state_pos_noise_std == 0.0
            and s.state_vel_noise_std == 0.0
            and s.state_acc_noise_std == 0.0
            and s.state_att_noise_std == 0.0
            and s.state_omega_noise_std == 0.0
        )
        self.reset()

    # ------------------------------------------------------------------------------------------------
    @property
    def t(self) -> float:
        """Simulation time [s]."""
        return self._k * self.dt

    def default_start(self) -> tuple[np.ndarray, np.ndarray]:
        """The scene's free-space start pose ``(p_W, R_WB)`` for this vehicle."""
        return default_start_pose(self.scene, self.vehicle, self.params.scene)

    def reset(
        self, p_W: np.ndarray | None = None, R_WB: np.ndarray | None = None, omega_hz: np.ndarray | None = None
    ) -> SensorFrame:
        """Start a run at rest, the rotors at the speeds that hover under the nominal map.

        Every noise stream restarts from the seed, so a reset run repeats exactly. The external wrench is
        cleared.

        Args:
            p_W: (3,) CoM position [m]; default the scene's start position.
            R_WB: (3, 3) attitude; default the scene's start attitude.
            omega_hz: (n,) initial rotor speeds [Hz] (clipped to the limits); default the nominal hover
                speeds at ``R_WB``.

        Returns:
            The frame at t = 0.
        """
        p0, R0 = self.default_start()
        p = p0 if p_W is None else np.asarray(p_W, dtype=float)
        R = R0 if R_WB is None else np.asarray(R_WB, dtype=float)
        if p.shape != (3,) or R.shape != (3, 3) or not (np.all(np.isfinite(p)) and np.all(np.isfinite(R))):
            raise InputError("reset: p_W must be a finite (3,) vector and R_WB a finite (3, 3) matrix")
        if np.max(np.abs(R.T @ R - np.eye(3))) > 1e-6 or np.linalg.det(R) < 0:
            raise InputError("reset: R_WB is not a rotation matrix")
        m, d = self.model, self.data
        mujoco.mj_resetData(m, d)
        d.qpos[self._qp : self._qp + 3] = p
        d.qpos[self._qp + 3 : self._qp + 7] = quat_wxyz_from_R(R)
        self._k = 0
        self._truth = None
        self._ext_f = [0.0, 0.0, 0.0]
        self._ext_m = [0.0, 0.0, 0.0]
        self._has_ext = False
        if omega_hz is None:
            self.rotors.reset(self.hover_speeds_hz(R))
        else:
            w = np.asarray(omega_hz, dtype=float)
            if w.shape != self._n_shape or not np.all(np.isfinite(w)):
                raise InputError(f"reset: omega_hz must be a finite vector of shape {self._n_shape}")
            self.rotors.reset(w)
        streams = [np.random.default_rng(s) for s in np.random.SeedSequence(self.seed).spawn(_N_STREAMS)]
        s = self.params.sensors
        self.imu.reset(streams[0], streams[1])
        self.mocap.reset(streams[2], d.qpos[self._qp : self._qp + 3].copy(), d.qpos[self._qp + 3 : self._qp + 7].copy())
        self._rotor_noise = NoiseStream(streams[3], s.rotor_speed_noise_std_hz, self.vehicle.n_rotors)
        state_scale = np.repeat(
            [
                s.state_pos_noise_std,
                s.state_vel_noise_std,
                s.state_acc_noise_std,
                s.state_att_noise_std,
                s.state_omega_noise_std,
            ],
            3,
        )
        self._state_noise = NoiseStream(streams[4], state_scale, 15, as_list=True)
        self._apply_wrench(recompute_rotors=True)
        mujoco.mj_forward(m, d)
        return self._frame()

    def set_external_wrench(self, f_W: np.ndarray, m_W: np.ndarray | None = None, at: str = "ee") -> None:
        """Add a constant wrench every step until changed (disturbances, tests).

        Args:
            f_W: (3,) force, world frame [N].
            m_W: (3,) moment, world frame [N·m] (default zero).
            at: "ee" applies the force at the EE tip (adding its moment about the CoM), "com" at the CoM.

        Raises:
            InputError: bad shape, non-finite value or unknown ``at``.
        """
        if at not in ("ee", "com"):
            raise InputError(f"set_external_wrench: at must be 'ee' or 'com', got {at!r}")
        f = np.asarray(f_W, dtype=float)
        mo = np.zeros(3) if m_W is None else np.asarray(m_W, dtype=float)
        if f.shape != (3,) or mo.shape != (3,) or not (np.all(np.isfinite(f)) and np.all(np.isfinite(mo))):
            raise InputError("set_external_wrench: f_W and m_W must be finite (3,) vectors")
        self._ext_f = f.tolist()
        self._ext_m = mo.tolist()
        self._ext_at_ee = at == "ee"
        self._has_ext = bool(np.any(f != 0.0) or np.any(mo != 0.0))

    # ------------------------------------------------------------------------------------------------
    def step(self, cmd: RotorCommand) -> SensorFrame:
        """Advance one control period under ``cmd`` and return the frame at the new time.

        Args:
            cmd: rotor speed set-points [Hz], shape (n,). Out-of-range values are clipped to the vehicle's
                limits; a NaN entry is ignored (that rotor holds its speed).

        Returns:
            The sensor frame at ``t + dt``.
        """
        if cmd.omega_hz.shape != self._n_shape:
            raise InputError(f"step: omega_hz must have shape {self._n_shape}, got {cmd.omega_hz.shape}")
        m, d = self.model, self.data
        for i in range(self.substeps):
            mujoco.mj_Euler(m, d)
            last = i == self.substeps - 1
            if last:
                self.rotors.step(cmd.omega_hz)
            self._apply_wrench(recompute_rotors=last)
            mujoco.mj_forward(m, d)
        self._k += 1
        self._truth = None
        return self._frame()

    def _apply_wrench(self, recompute_rotors: bool) -> None:
        """Write rotor and external wrenches at the CoM, world frame, into ``xfrc_applied``."""
        d = self.data
        if recompute_rotors:
            self.aero.wrench_B(self.rotors.u_hz2, out=self._w_B)
        qp = self._qp
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = R9_from_quat(d.qpos[qp + 3 : qp + 7].tolist())
        fx, fy, fz, mx, my, mz = self._w_B.tolist()
        Fx = r00 * fx + r01 * fy + r02 * fz
        Fy = r10 * fx + r11 * fy + r12 * fz
        Fz = r20 * fx + r21 * fy + r22 * fz
        Mx = r00 * mx + r01 * my + r02 * mz
        My = r10 * mx + r11 * my + r12 * mz
        Mz = r20 * mx + r21 * my + r22 * mz
        if self._has_ext:
            ex, ey, ez = self._ext_f
            Fx, Fy, Fz = Fx + ex, Fy + ey, Fz + ez
            Mx, My, Mz = Mx + self._ext_m[0], My + self._ext_m[1], Mz + self._ext_m[2]
            if self._ext_at_ee:  # moment of the force applied at the EE tip: (R p_E_B) x f
                px, py, pz = self._p_E_B_list
                rx = r00 * px + r01 * py + r02 * pz
                ry = r10 * px + r11 * py + r12 * pz
                rz = r20 * px + r21 * py + r22 * pz
                Mx += ry * ez - rz * ey
                My += rz * ex - rx * ez
                Mz += rx * ey - ry * ex
        d.xfrc_applied[self._body] = (Fx, Fy, Fz, Mx, My, Mz)

    def _frame(self) -> SensorFrame:
        d = self.data
        qp, qv = self._qp, self._qv
        t = self._k * self.dt
        qpos = d.qpos.tolist()
        qvel = d.qvel.tolist()
        qacc = d.qacc.tolist()
        R9 = d.xmat[self._body].tolist()
        p_W, q_WB = qpos[qp : qp + 3], qpos[qp + 3 : qp + 7]
        v_W, omega_B = qvel[qv : qv + 3], qvel[qv + 3 : qv + 6]
        a_W, omega_dot_B = qacc[qv : qv + 3], qacc[qv + 3 : qv + 6]
        acc_B, gyro_B = self.imu.measure(R9, a_W, omega_B, omega_dot_B)
        rotor_hz = self.rotors.omega_hz + self._rotor_noise.next()
        sample = self.mocap.step(self._k, t, p_W, q_WB)
        state = self._state(t, p_W, v_W, a_W, q_WB, R9, omega_B) if self._provide_state else None
        if sample is None:
            return SensorFrame(t=t, imu_acc_B=acc_B, imu_gyro_B=gyro_B, rotor_hz=rotor_hz, state=state)
        return SensorFrame(
            t=t,
            imu_acc_B=acc_B,
            imu_gyro_B=gyro_B,
            rotor_hz=rotor_hz,
            mocap_new=True,
            mocap_t=sample.t,
            mocap_p_W=sample.p_W,
            mocap_q_WB=sample.q_WB,
            state=state,
        )

    def _state(self, t: float, p_W: list, v_W: list, a_W: list, q_WB: list, R9: list, omega_B: list) -> StateEstimate:
        """Ground truth plus white noise (float arithmetic; exact copies when the noise is zero)."""
        if self._state_exact:
            return StateEstimate(
                t=t,
                p_W=np.array(p_W),
                v_W=np.array(v_W),
                a_W=np.array(a_W),
                R_WB=np.array(R9).reshape(3, 3),
                omega_B=np.array(omega_B),
            )
        e = self._state_noise.next()
        qn = self._qn
        quat_perturb(q_WB, e[9:12], qn)
        return StateEstimate(
            t=t,
            p_W=np.array((p_W[0] + e[0], p_W[1] + e[1], p_W[2] + e[2])),
            v_W=np.array((v_W[0] + e[3], v_W[1] + e[4], v_W[2] + e[5])),
            a_W=np.array((a_W[0] + e[6], a_W[1] + e[7], a_W[2] + e[8])),
            R_WB=np.array(R9_from_quat(qn)).reshape(3, 3),
            omega_B=np.array((omega_B[0] + e[12], omega_B[1] + e[13], omega_B[2] + e[14])),
        )

    # ------------------------------------------------------------------------------------------------
    @property
    def truth(self) -> GroundTruth:
        """Ground truth at the current time (computed on first access after a step)."""
        if self._truth is None:
            self._truth = self._ground_truth()
        return self._truth

    def _ground_truth(self) -> GroundTruth:
        m, d = self.model, self.data
        qp, qv = self._qp, self._qv
        p_E_W = d.site_xpos[self._ee_site].copy()
        force = np.zeros(3)
        moment = np.zeros(3)
        in_contact = False
        other = False
        f6 = self._cf6
        ncon = d.ncon
        if ncon:
            g1 = d.contact.geom1
            g2 = d.contact.geom2
            frames = d.contact.frame
            pos = d.contact.pos
            for c in range(ncon):
                r1, r2 = self._robot_geom[g1[c]], self._robot_geom[g2[c]]
                if r1 == r2:
                    continue
                geom = g1[c] if r1 else g2[c]
                if not self._ee_geom[geom]:
                    other = True
                    continue
                in_contact = True
                mujoco.mj_contactForce(m, d, c, f6)
                F = frames[c].reshape(3, 3)
                # mj_contactForce gives the force on geom2, in the contact frame (rows of F).
                sign = -1.0 if r1 else 1.0
                f_W = sign * (F.T @ f6[:3])
                force += f_W
                moment += sign * (F.T @ f6[3:]) + np.cross(pos[c] - p_E_W, f_W)
        return GroundTruth(
            t=self.t,
            p_W=d.qpos[qp : qp + 3].copy(),
            v_W=d.qvel[qv : qv + 3].copy(),
            a_W=d.qacc[qv : qv + 3].copy(),
            R_WB=d.xmat[self._body].reshape(3, 3).copy(),
            omega_B=d.qvel[qv + 3 : qv + 6].copy(),
            rotor_hz=self.rotors.omega_hz.copy(),
            rotor_wrench_B=self._w_B.copy(),
            contact_force_W=force,
            contact_moment_W=moment,
            in_contact=in_contact,
            p_E_W=p_E_W,
            other_contact=other,
        )

    def hover_speeds_hz(self, R_WB: np.ndarray | None = None) -> np.ndarray:
        """(n,) speeds [Hz] that hover at ``R_WB`` under the nominal map (clipped to the limits)."""
        u = self.vehicle.hover_input(R_WB)
        w = np.sign(u) * np.sqrt(np.abs(u))
        return np.clip(w, self.vehicle.omega_min_hz, self.vehicle.omega_max_hz)
