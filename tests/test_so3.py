import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from omnirotor import so3


def random_R(rng):
    return Rotation.random(random_state=rng.integers(1 << 31)).as_matrix()


def test_hat_vee_cross():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=3), rng.normal(size=3)
    np.testing.assert_allclose(so3.hat(a) @ b, np.cross(a, b))
    np.testing.assert_allclose(so3.vee(so3.hat(a)), a)


def test_elementary_rotations_match_spec():
    t = 0.3
    np.testing.assert_allclose(so3.rot_y(t) @ [0, 0, 1], [math.sin(t), 0, math.cos(t)])
    np.testing.assert_allclose(so3.rot_x(t) @ [0, 0, 1], [0, -math.sin(t), math.cos(t)])


def test_exp_log_roundtrip_and_scipy_agreement():
    rng = np.random.default_rng(1)
    for _ in range(50):
        phi = rng.normal(size=3)
        phi *= rng.uniform(0, 3.0) / np.linalg.norm(phi)
        R = so3.exp_so3(phi)
        np.testing.assert_allclose(R, Rotation.from_rotvec(phi).as_matrix(), atol=1e-12)
        np.testing.assert_allclose(so3.log_so3(R), phi, atol=1e-9)
    # near pi
    phi = np.array([0.0, 0.0, math.pi - 1e-6])
    np.testing.assert_allclose(so3.exp_so3(so3.log_so3(so3.exp_so3(phi))), so3.exp_so3(phi), atol=1e-6)


def test_quaternion_order_and_hamilton_convention():
    rng = np.random.default_rng(2)
    for _ in range(20):
        R = random_R(rng)
        q_xyzw = Rotation.from_matrix(R).as_quat()
        q = so3.quat_wxyz_from_xyzw(q_xyzw)
        np.testing.assert_allclose(so3.R_from_quat_wxyz(q), R, atol=1e-12)
        q2 = so3.quat_wxyz_from_R(R)
        assert q2[0] >= 0
        np.testing.assert_allclose(abs(q2 @ q), 1.0, atol=1e-12)
        np.testing.assert_allclose(so3.quat_xyzw_from_wxyz(q), q_xyzw)
    # 90 deg about z: w = cos45, z = sin45, and it maps x to y
    q = np.array([math.cos(math.pi / 4), 0, 0, math.sin(math.pi / 4)])
    np.testing.assert_allclose(so3.R_from_quat_wxyz(q) @ [1, 0, 0], [0, 1, 0], atol=1e-12)


def test_rpy_zyx_roundtrip():
    rng = np.random.default_rng(3)
    for _ in range(20):
        rpy = rng.uniform([-3, -1.4, -3], [3, 1.4, 3])
        R = so3.R_from_rpy(*rpy)
        np.testing.assert_allclose(R, Rotation.from_euler("ZYX", rpy[::-1]).as_matrix(), atol=1e-12)
        np.testing.assert_allclose(so3.rpy_from_R(R), rpy, atol=1e-9)


@pytest.mark.parametrize("scale", [1e-3, 0.1])
def test_project_to_SO3(scale):
    rng = np.random.default_rng(4)
    R = random_R(rng)
    P = so3.project_to_SO3(R + scale * rng.normal(size=(3, 3)))
    np.testing.assert_allclose(P @ P.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(P) == pytest.approx(1.0)


# -- the compiled helpers of the 1 kHz kernels (controller and simulator) -----------------------------------------


def _q_scipy(q_wxyz):
    """SciPy's rotation of a wxyz quaternion (SciPy stores xyzw)."""
    return Rotation.from_quat(so3.quat_xyzw_from_wxyz(q_wxyz))


def _unit_quats(rng, n):
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def test_compiled_quat_mul_is_hamiltons_product_as_scipy_composes_it():
    rng = np.random.default_rng(10)
    for a, b in zip(_unit_quats(rng, 30), _unit_quats(rng, 30), strict=True):
        ab = np.array(so3.quat_mul(*a, *b))
        # Hamilton: R(a ⊗ b) = R(a) R(b); SciPy's composition a * b is the same product.
        want = (_q_scipy(a) * _q_scipy(b)).as_matrix()
        np.testing.assert_allclose(so3.R_from_quat_wxyz(ab), want, atol=1e-14)
        # wxyz -> xyzw -> wxyz round trip of the product, through SciPy, up to the quaternion's sign.
        back = so3.quat_wxyz_from_xyzw((_q_scipy(a) * _q_scipy(b)).as_quat())
        np.testing.assert_allclose(abs(back @ ab), 1.0, atol=1e-14)
    # Not commutative: x then y differs from y then x.
    qx = np.array([math.cos(0.4), math.sin(0.4), 0.0, 0.0])
    qy = np.array([math.cos(0.4), 0.0, math.sin(0.4), 0.0])
    assert not np.allclose(so3.quat_mul(*qx, *qy), so3.quat_mul(*qy, *qx))


def test_compiled_rotation_matrix_and_exponentials_match_scipy():
    rng = np.random.default_rng(11)
    R = np.empty((3, 3))
    R9 = np.empty(12)
    out = np.empty(5)
    for q in _unit_quats(rng, 30):
        so3.R_from_quat_into(q, R)
        np.testing.assert_allclose(R, _q_scipy(q).as_matrix(), atol=1e-15)
        so3.R9_from_quat_into(q[0], q[1], q[2], q[3], R9, 3)  # at an offset
        np.testing.assert_array_equal(R9[3:], R.ravel())
    for phi in [*rng.normal(0.0, 1.0, (20, 3)), np.array([1e-7, -2e-7, 5e-8]), np.zeros(3)]:
        so3.exp_so3_into(phi[0], phi[1], phi[2], R)
        np.testing.assert_allclose(R, Rotation.from_rotvec(phi).as_matrix(), atol=1e-15)
        q = np.array(so3.quat_of_rotvec(*phi))
        want = so3.quat_wxyz_from_xyzw(Rotation.from_rotvec(phi).as_quat())
        np.testing.assert_allclose(q * np.sign(q @ want), want, atol=1e-15)
        so3.log_so3_into(R, out, 2)
        if np.linalg.norm(phi) < math.pi:
            np.testing.assert_allclose(out[2:], phi, atol=1e-12)
        np.testing.assert_allclose(out[2:], Rotation.from_matrix(R).as_rotvec(), atol=1e-12)


def test_compiled_exp_has_the_hat_of_its_argument_as_derivative():
    """d/dt Exp(t phi) at 0 is [phi]x; along any direction d, dExp(phi) d = Exp(phi) [J_r(phi) d]x."""
    rng = np.random.default_rng(12)
    R = np.empty((3, 3))
    h = 1e-6
    for phi in rng.normal(0.0, 1.0, (10, 3)):
        so3.exp_so3_into(*(h * phi), R)
        Rp = R.copy()
        so3.exp_so3_into(*(-h * phi), R)
        np.testing.assert_allclose((Rp - R) / (2 * h), so3.hat(phi), atol=1e-8)
        # Derivative along a general direction d: (Exp(phi + h d) - Exp(phi - h d)) / 2h = Exp(phi) [J_r d]x.
        d = rng.normal(size=3)
        so3.exp_so3_into(*(phi + h * d), R)
        Rp = R.copy()
        so3.exp_so3_into(*(phi - h * d), R)
        fd = (Rp - R) / (2 * h)
        th = np.linalg.norm(phi)
        K = so3.hat(phi)
        J_r = np.eye(3) - (1 - math.cos(th)) / th**2 * K + (th - math.sin(th)) / th**3 * (K @ K)
        np.testing.assert_allclose(fd, so3.exp_so3(phi) @ so3.hat(J_r @ d), atol=1e-7)


@pytest.mark.parametrize("frame", ["body", "world"])
def test_compiled_quaternion_integration_turns_by_the_rate_in_its_frame(frame):
    """One step of ``omega dt`` equals SciPy's rotation composed on the right (body) or left (world); finite
    differences of the integrated attitude give ``R [omega]x`` (body) and ``[omega]x R`` (world)."""
    rng = np.random.default_rng(13)
    for q0 in _unit_quats(rng, 10):
        omega, dt = rng.normal(0.0, 2.0, 3), 1e-3
        q = q0.copy()
        if frame == "body":
            so3.quat_integrate_body_into(q, *(omega * dt))
            want = (_q_scipy(q0) * Rotation.from_rotvec(omega * dt)).as_matrix()
        else:
            assert so3.quat_integrate_world_into(q, *omega, dt)
            want = (Rotation.from_rotvec(omega * dt) * _q_scipy(q0)).as_matrix()
        assert abs(np.linalg.norm(q) - 1.0) < 1e-15
        np.testing.assert_allclose(so3.R_from_quat_wxyz(q), want, atol=1e-14)
        # Central difference of R(q(t)) at t = 0 with steps +-h.
        h = 1e-6
        qp, qm = q0.copy(), q0.copy()
        if frame == "body":
            so3.quat_integrate_body_into(qp, *(omega * h))
            so3.quat_integrate_body_into(qm, *(-omega * h))
            want = so3.R_from_quat_wxyz(q0) @ so3.hat(omega)
        else:
            so3.quat_integrate_world_into(qp, *omega, h)
            so3.quat_integrate_world_into(qm, *(-omega), h)
            want = so3.hat(omega) @ so3.R_from_quat_wxyz(q0)
        fd = (so3.R_from_quat_wxyz(qp) - so3.R_from_quat_wxyz(qm)) / (2 * h)
        np.testing.assert_allclose(fd, want, atol=1e-8)
    # A zero rate leaves the world-frame integration alone (and says so); the body one stays exact.
    q = q0.copy()
    assert not so3.quat_integrate_world_into(q, 0.0, 0.0, 0.0, 1e-3)
    np.testing.assert_array_equal(q, q0)
    so3.quat_integrate_body_into(q, 0.0, 0.0, 0.0)
    np.testing.assert_allclose(q, q0, atol=1e-16)


def test_compiled_perturbation_is_the_first_order_right_product():
    rng = np.random.default_rng(14)
    out = np.empty(4)
    for q in _unit_quats(rng, 20):
        d = rng.normal(0.0, 0.01, 3)
        so3.quat_perturb_into(q, d, out)
        want = np.array(so3.quat_mul(*q, 1.0, *(0.5 * d)))
        np.testing.assert_allclose(out, want / np.linalg.norm(want), atol=1e-15)
        # To first order, the rotation Exp(d) on the right (body frame).
        np.testing.assert_allclose(
            so3.R_from_quat_wxyz(out), (_q_scipy(q) * Rotation.from_rotvec(d)).as_matrix(), atol=1e-5
        )


def test_so3_imports_nothing_of_the_package():
    """The ground floor: the controller and the simulator both use it and must not import each other."""
    import ast
    from pathlib import Path

    tree = ast.parse(Path(so3.__file__).read_text())
    imported = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    imported |= {n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    assert not any(m.split(".")[0] == "omnirotor" for m in imported), imported
