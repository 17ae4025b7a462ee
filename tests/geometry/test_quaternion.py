import numpy as np
import pytest

from sianms_cli.errors import SianmsError
from sianms_cli.geometry.quaternion import (
    matrix_to_quat,
    quat_multiply,
    quat_to_matrix,
    quat_yaw,
    yaw_to_quat,
)

S = np.sqrt(0.5)


def random_quats(n: int, seed: int) -> np.ndarray:
    q = np.random.default_rng(seed).normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def test_quat_to_matrix_quarter_turns():
    yaw90 = quat_to_matrix([S, 0, 0, S])
    roll90 = quat_to_matrix([S, S, 0, 0])
    np.testing.assert_allclose(yaw90, [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-15)
    np.testing.assert_allclose(roll90, [[1, 0, 0], [0, 0, -1], [0, 1, 0]], atol=1e-15)


def test_quat_to_matrix_normalises_and_broadcasts():
    q = random_quats(6, seed=0).reshape(2, 3, 4)
    matrices = quat_to_matrix(3.0 * q)
    assert matrices.shape == (2, 3, 3, 3)
    np.testing.assert_allclose(matrices, quat_to_matrix(q), atol=1e-15)
    identity = np.einsum("...ji,...jk->...ik", matrices, matrices)
    np.testing.assert_allclose(identity, np.broadcast_to(np.eye(3), identity.shape), atol=1e-14)
    np.testing.assert_allclose(np.linalg.det(matrices), 1.0, atol=1e-14)


def test_quat_to_matrix_rejects_zero_quaternion():
    with pytest.raises(SianmsError):
        quat_to_matrix([0.0, 0.0, 0.0, 0.0])


@pytest.mark.parametrize(
    "matrix, quat",
    [
        (np.eye(3), [1, 0, 0, 0]),
        (np.diag([1.0, -1.0, -1.0]), [0, 1, 0, 0]),
        (np.diag([-1.0, 1.0, -1.0]), [0, 0, 1, 0]),
        (np.diag([-1.0, -1.0, 1.0]), [0, 0, 0, 1]),
    ],
)
def test_matrix_to_quat_every_pivot(matrix, quat):
    np.testing.assert_allclose(matrix_to_quat(matrix), quat, atol=1e-15)


def test_matrix_to_quat_round_trip_with_nonnegative_w():
    q = random_quats(500, seed=1)
    recovered = matrix_to_quat(quat_to_matrix(q))
    assert np.all(recovered[:, 0] >= 0)
    expected = np.where(q[:, :1] < 0, -q, q)
    np.testing.assert_allclose(recovered, expected, atol=1e-12)


def test_quat_multiply_unit_products():
    i, j, k = np.eye(4)[1], np.eye(4)[2], np.eye(4)[3]
    np.testing.assert_array_equal(quat_multiply(i, j), k)
    np.testing.assert_array_equal(quat_multiply(j, i), -k)
    np.testing.assert_array_equal(quat_multiply(i, i), [-1, 0, 0, 0])


def test_quat_multiply_composes_rotations():
    a, b = random_quats(50, seed=2), random_quats(50, seed=3)
    np.testing.assert_allclose(
        quat_to_matrix(quat_multiply(a, b)), quat_to_matrix(a) @ quat_to_matrix(b), atol=1e-14
    )


def test_yaw_to_quat_values():
    np.testing.assert_allclose(yaw_to_quat(np.pi / 2), [S, 0, 0, S], atol=1e-16)
    np.testing.assert_array_equal(yaw_to_quat(np.zeros((2, 3))).shape, (2, 3, 4))


def test_quat_yaw_round_trip():
    yaws = np.linspace(-np.pi + 1e-6, np.pi, 101)
    np.testing.assert_allclose(quat_yaw(yaw_to_quat(yaws)), yaws, atol=1e-12)


def test_quat_yaw_ignores_pitch():
    # Pitching the x axis by 20 deg tilts it to (cos 20, 0, -sin 20); yawing 30 deg keeps
    # its heading at 30 deg.
    pitch = np.radians(20.0)
    q_pitch = np.array([np.cos(pitch / 2), 0.0, np.sin(pitch / 2), 0.0])
    q = quat_multiply(yaw_to_quat(np.radians(30.0)), q_pitch)
    assert quat_yaw(q) == pytest.approx(np.radians(30.0), abs=1e-12)


def test_quat_yaw_of_real_lidar(set_a_lidar_rotation):
    # Reference section 4: the Set A LIDAR_TOP x axis points at -89.88 deg.
    assert np.degrees(quat_yaw(set_a_lidar_rotation)) == pytest.approx(-89.88, abs=0.005)
