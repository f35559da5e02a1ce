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
compliant tool (rod and tip on spring-damper joints, :mod:`omnirotor.sim.model`); collision-enabled propeller
disks; rotor lag 25 ms (SPEC §1.4). With ``substeps`` > 1 the rotor wrench is computed once per control
period and held (its world direction follows the body).
"""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np

from omnirotor._jit import mujoco_timer_address
from omnirotor.blocks import new_records
from omnirotor.errors import InputError
from omnirotor.messages import RotorCommand, SensorFrame, frame_dtype
from omnirotor.sim import step as _step
from omnirotor.sim.aero import make_aero
from omnirotor.sim.airflow import AirflowForce, scene_surfaces, wake_radius
from omnirotor.sim.contact import EeContact, friction_reset, friction_step, other_contact
from omnirotor.sim.faults import FaultSchedule
from omnirotor.sim.model import BODY_NAME, EE_ROD_GEOM, EE_SITE, EE_TIP_GEOM, build_mjcf
from omnirotor.sim.model_cache import compiled_model
from omnirotor.sim.params import SimParams
from omnirotor.sim.rotors import RotorBank
from omnirotor.sim.scenes import SCENES, SceneAnchors, default_start_pose, scene_anchors
from omnirotor.sim.sensors import STATE_EXACT, STATE_NOISY, STATE_NONE, NoiseStream, Sensors
from omnirotor.so3 import quat_wxyz_from_R
from omnirotor.vehicle import VehicleParams

__all__ = ["Simulator", "GroundTruth", "TRUTH_ROW_SIZE"]

TRUTH_ROW_SIZE = _step.TRUTH_ROW_SIZE
"""Entries of :meth:`Simulator.truth_row` before the rotor speeds: t, p, v, R (9), omega, p_E, contact f, m, flag."""


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
        model: the ``mujoco.MjModel`` stepped (textures of 2 px; render with :attr:`render_model`).
        data: the ``mujoco.MjData``.
        aero: the truth aerodynamics; ``aero.wrench_B(u_hz2)`` gives the (6,) body wrench.
        rotors: the rotor speed states (:class:`~omnirotor.sim.rotors.RotorBank`).
        airflow: the recirculating wake's force at the CoM (:class:`~omnirotor.sim.airflow.AirflowForce`).
        sensors: the sensors (:class:`~omnirotor.sim.sensors.Sensors`): ``imu`` (its drawn biases:
            ``imu.acc_bias_B``, ``imu.gyro_bias_B``), ``mocap``, the noise streams.
        imu: ``sensors.imu``.
        mocap: ``sensors.mocap``.
        contact: the EE contact wrench (:class:`~omnirotor.sim.contact.EeContact`).
        faults: the fault schedule the step applies (:class:`~omnirotor.sim.faults.FaultSchedule`; empty
            unless filled, e.g. by :func:`omnirotor.experiments.faults.plant_simulator`).
        dt: control period [s].

    Args:
        vehicle: the vehicle.
        scene: one of :data:`SCENES`.
        params: simulator parameters (default :class:`SimParams`).
        seed: seed of every noise source (same seed, same run).
        reset: start at rest at the scene's start (:meth:`reset`); False leaves the first :meth:`reset` to the
            caller, before anything else (for a caller that resets at once anyway, as
            :func:`~omnirotor.experiments.loop.run_closed_loop` does: a reset draws every noise
            stream's first block).

    Raises:
        InputError: unknown scene.
    """

    def __init__(
        self,
        vehicle: VehicleParams,
        scene: str = "free",
        params: SimParams | None = None,
        seed: int = 0,
        *,
        reset: bool = True,
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
        self.model = compiled_model(vehicle, scene, p.scene, p.dt / p.substeps)  # 2 px textures: see render_model
        self._render_model: mujoco.MjModel | None = None
        self.data = mujoco.MjData(self.model)
        m = self.model
        self._body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, BODY_NAME)
        self._ee_site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, EE_SITE)
        robot = np.flatnonzero(m.body_rootid[m.geom_bodyid] == self._body)  # the vehicle and its tool
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

        s = p.sensors
        state_exact = (
            s.state_pos_noise_std == 0.0
            and s.state_vel_noise_std == 0.0
            and s.state_acc_noise_std == 0.0
            and s.state_att_noise_std == 0.0
            and s.state_omega_noise_std == 0.0
        )
        if not p.provide_state:
            state_mode = STATE_NONE
        else:
            state_mode = STATE_EXACT if state_exact else STATE_NOISY
        # The compiled step's record: the blocks live in its fields (views), the wiring beside them.
        self._rec = np.zeros(1, _step.SIM_DTYPE)
        rec = self._rec
        self.aero = make_aero(vehicle, p.aero)
        self.rotors = RotorBank(vehicle, p.rotors, p.dt, seed=self.seed)
        self.rotors.adopt(rec["rotor_par"], rec["rotors"])
        self.airflow = AirflowForce(
            p.airflow, p.dt, seed=self.seed, weight_N=vehicle.weight, surfaces=scene_surfaces(scene, p.scene),
            wake_radius_m=wake_radius(vehicle),
        )  # fmt: skip
        self.airflow.adopt(rec["airflow_par"], rec["airflow"])
        self.sensors = Sensors(
            p.sensors, vehicle.gravity, p.dt, vehicle.n_rotors, state_mode, self.seed, rec["sensors"]
        )
        self.imu = self.sensors.imu
        self.mocap = self.sensors.mocap
        self.contact = EeContact(
            m, par=rec["contact_par"], friction=rec["friction"], data=self.data, mu=p.scene.friction,
            tool_mass=p.scene.tool_mass,
        )  # fmt: skip
        self.faults = FaultSchedule(
            vehicle.n_rotors, float(vehicle.omega_min_hz), float(vehicle.omega_max_hz), rec["faults"]
        )
        self._p_E_B = vehicle.p_E_B_array.copy()
        n = vehicle.n_rotors
        self._n_shape = (n,)
        d = self.data
        # Views of MuJoCo's arrays resolved once (MjData never reallocates them).
        qp, qv = self._qp, self._qv
        self._pose = d.qpos[qp : qp + 7]
        self._xfrc = d.xfrc_applied[self._body]
        mj = rec["mj"]
        mj["model"], mj["data"], mj["substeps"] = m._address, d._address, self.substeps
        mj["pose"], mj["vel"], mj["acc"] = self._pose.ctypes.data, d.qvel[qv:].ctypes.data, d.qacc[qv:].ctypes.data
        mj["R_WB"], mj["p_E_W"] = d.xmat[self._body].ctypes.data, d.site_xpos[self._ee_site].ctypes.data
        mj["sensordata"], mj["n_sensordata"] = d.sensordata.ctypes.data, d.sensordata.shape[0]
        mj["xfrc"] = self._xfrc.ctypes.data
        mj["timer"] = mujoco_timer_address()
        self._ext = rec["ext"]
        self._ext["p_E_B"] = self._p_E_B
        self._w_B = rec["w_B"][0]
        self._R9 = rec["R9"][0]  # apply_wrench's scratch
        self._k = 0
        self._truth: GroundTruth | None = None
        self._frame_buf = new_records(frame_dtype(n))  # the frame record (omnirotor.messages) of the last step
        self._row = np.zeros(_step.TRUTH_ROW_SIZE + n)  # the truth row of the last step
        self._last_substep = self.substeps - 1
        # The aero model and rotor bank the compiled step was set up for (see step()).
        self._fused_aero = self.aero if hasattr(self.aero, "kernel_model") else None
        self._fused_rotors = self.rotors
        if reset:
            self.reset()

    # ------------------------------------------------------------------------------------------------
    @property
    def render_model(self) -> mujoco.MjModel:
        """The model to render :attr:`data` with: :attr:`model` with full-size textures (compiled on first use).

        The simulated model carries 2-pixel textures (:func:`~omnirotor.sim.model.build_mjcf`): generating the
        full ones took most of a run's model compilation. Both have the same bodies, geoms and materials.
        """
        if self._render_model is None:
            p = self.params
            xml = build_mjcf(self.vehicle, self.scene_name, p.scene, p.dt / p.substeps)
            self._render_model = mujoco.MjModel.from_xml_string(xml)
        return self._render_model

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
        self._ext[0] = 0
        self._ext["p_E_B"] = self._p_E_B
        if omega_hz is None:
            self.rotors.reset(self.hover_speeds_hz(R))
        else:
            w = np.asarray(omega_hz, dtype=float)
            if w.shape != self._n_shape or not np.all(np.isfinite(w)):
                raise InputError(f"reset: omega_hz must be a finite vector of shape {self._n_shape}")
            self.rotors.reset(w)
        self.sensors.reset(self._pose[0:3].copy(), self._pose[3:7].copy())
        self.faults.reset()
        self.airflow.reset()
        rec = self.kernel_state
        if rec is not None:  # the project's own rotor and truth models: one compiled call
            _step.reset_forward(rec)
        else:
            self._apply_wrench(recompute_rotors=True)
            friction_reset(self._rec["friction"][0])
            mujoco.mj_forward(m, d)
            self._friction_step()
        self.sensors.refill()
        _step.observe(self._rec, 0, self.dt, self._frame_buf, self._row)
        return SensorFrame.from_record(self._frame_buf)

    @property
    def kernel_state(self) -> np.ndarray | None:
        """The (1,) :data:`~omnirotor.sim.step.SIM_DTYPE` record of :func:`omnirotor.sim.step.sim_step`.

        For a compiled loop (valid until the simulator is dropped); None when the rotor or truth model was
        replaced by one without a kernel.
        """
        if not (self.aero is self._fused_aero and self.rotors is self._fused_rotors):
            return None
        aero = self._rec["aero"]
        model = self.aero.kernel_model
        if aero["model"][0] != model.ctypes.data:  # the model array the record points to is the aero's
            aero["kind"] = self.aero.kernel_kind
            aero["model"], aero["rows"], aero["cols"] = model.ctypes.data, model.shape[0], model.shape[1]
            self._aero_model = model  # kept alive with the record
        return self._rec

    @property
    def noise_streams(self) -> tuple[NoiseStream, ...]:
        """The noise streams a compiled step reads (refill the exhausted ones between compiled calls)."""
        return self.sensors.noise_streams

    @property
    def frame_record(self) -> np.ndarray:
        """The (1,) frame record (:mod:`omnirotor.messages`) of the last step, owned by the simulator."""
        return self._frame_buf

    @property
    def step_index(self) -> int:
        """Control periods since :meth:`reset`."""
        return self._k

    @step_index.setter
    def step_index(self, k: int) -> None:
        # A compiled loop that stepped the simulator itself reports where it stopped.
        self._k = int(k)
        self._truth = None

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
        e = self._ext
        e["f_W"], e["m_W"] = f, mo
        e["at_ee"] = at == "ee"
        e["active"] = bool(np.any(f != 0.0) or np.any(mo != 0.0))

    # ------------------------------------------------------------------------------------------------
    def step(self, cmd: RotorCommand) -> SensorFrame:
        """Advance one control period under ``cmd`` and return the frame at the new time.

        Args:
            cmd: rotor speed set-points [Hz], shape (n,). Out-of-range values are clipped to the vehicle's
                limits; a NaN entry is ignored (that rotor holds its speed).

        Returns:
            The sensor frame at ``t + dt``.
        """
        omega_cmd = np.asarray(cmd.omega_hz, dtype=np.float64)
        if omega_cmd.shape != self._n_shape:
            raise InputError(f"step: omega_hz must have shape {self._n_shape}, got {omega_cmd.shape}")
        self.sensors.refill()
        self.faults.tell_due(self._k, self.dt)
        rec = self.kernel_state
        if rec is not None:  # the project's own rotor and truth models: one compiled call
            _step.sim_step(rec, omega_cmd, self._k, self.dt, self._frame_buf, self._row)
        else:
            m, d = self.model, self.data
            rotor_cmd = _step.pre_step(self._rec, omega_cmd, self._k, self.dt)
            for i in range(self.substeps):
                mujoco.mj_Euler(m, d)
                if i == self._last_substep:
                    self.rotors.step(rotor_cmd)
                    self.airflow.step(self._pose)
                self._apply_wrench(recompute_rotors=i == self._last_substep)
                mujoco.mj_forward(m, d)
                self._friction_step()
            _step.observe(self._rec, self._k + 1, self.dt, self._frame_buf, self._row)
        self._k += 1
        self._truth = None
        return SensorFrame.from_record(self._frame_buf)

    def _friction_step(self) -> None:
        """The tool's friction after ``mj_forward`` (:func:`omnirotor.sim.contact.friction_step`), in ``qacc``."""
        m, d = self.model, self.data
        if friction_step(self._rec["friction"][0], d.sensordata):
            mujoco.mj_fwdAcceleration(m, d)
            mujoco.mj_fwdConstraint(m, d)
            mujoco.mj_sensorAcc(m, d)

    def _apply_wrench(self, recompute_rotors: bool) -> None:
        """Write rotor and external wrenches at the CoM, world frame, into ``xfrc_applied``."""
        if recompute_rotors:
            self.aero.wrench_B(self.rotors.u_eff_hz2, out=self._w_B)
        _step.apply_wrench(self._pose, self._w_B, self._ext[0], self.airflow.f_W, self._xfrc, self._R9)

    # ------------------------------------------------------------------------------------------------
    @property
    def truth(self) -> GroundTruth:
        """Ground truth at the current time (computed on first access after a step)."""
        if self._truth is None:
            self._truth = self._ground_truth()
        return self._truth

    def truth_row(self, out: np.ndarray) -> None:
        """Write the ground truth at the current time as one flat row, for dense logs (no record is built).

        Layout of ``out[0 : TRUTH_ROW_SIZE + n]`` (n rotors; later entries are left alone): ``t`` [s],
        ``p_W`` (3), ``v_W`` (3), ``R_WB`` (9, row-major), ``omega_B`` (3), ``p_E_W`` (3),
        ``contact_force_W`` (3), ``contact_moment_W`` (3), ``in_contact`` (1.0 or 0.0), ``rotor_hz`` (n): the
        same values as :attr:`truth`.

        Args:
            out: a 1-D float64 array of at least ``TRUTH_ROW_SIZE + n`` entries.
        """
        out[: self._row.shape[0]] = self._row

    def _ground_truth(self) -> GroundTruth:
        d = self.data
        qv, body = self._qv, self._body
        p_E_W = d.site_xpos[self._ee_site].copy()
        self.contact.step(d.sensordata, p_E_W)
        c = self.contact.state[0]
        return GroundTruth(
            t=self.t,
            p_W=self._pose[0:3].copy(),
            v_W=d.qvel[qv : qv + 3].copy(),
            a_W=d.qacc[qv : qv + 3].copy(),
            R_WB=d.xmat[body].reshape(3, 3).copy(),
            omega_B=d.qvel[qv + 3 : qv + 6].copy(),
            rotor_hz=self.rotors.omega_hz.copy(),
            rotor_wrench_B=self._w_B.copy(),
            contact_force_W=c["f_W"].copy(),
            contact_moment_W=c["m_W"].copy(),
            in_contact=bool(c["in_contact"]),
            p_E_W=p_E_W,
            other_contact=other_contact(d, self._robot_geom, self._ee_geom),
        )

    def hover_speeds_hz(self, R_WB: np.ndarray | None = None) -> np.ndarray:
        """(n,) speeds [Hz] that hover at ``R_WB`` under the nominal map (clipped to the limits)."""
        u = self.vehicle.hover_input(R_WB)
        w = np.sign(u) * np.sqrt(np.abs(u))
        return np.clip(w, self.vehicle.omega_min_hz, self.vehicle.omega_max_hz)
