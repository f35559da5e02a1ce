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
