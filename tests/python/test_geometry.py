"""The shared rotation and ray math (worldsplat_models.geometry): known values, torch and numpy alike."""

import math

import numpy as np
import pytest
import torch

from worldsplat_models.geometry import (
    matrix_to_quaternion,
    normalize_quaternion,
    pixel_rays,
    plucker,
    quaternion_multiply,
    quaternion_to_matrix,
)


def axis_angle(axis, angle: float) -> np.ndarray:
    """Rodrigues' rotation matrix (an independent reference)."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def random_rotations(n: int, seed: int = 0) -> np.ndarray:
    q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(n, 3, 3)))
    return q * np.sign(np.linalg.det(q))[:, None, None]


def test_identity():
    ident = np.array([1.0, 0, 0, 0])
    np.testing.assert_array_equal(quaternion_to_matrix(ident), np.eye(3))
    np.testing.assert_array_equal(matrix_to_quaternion(np.eye(3)), ident)
    np.testing.assert_array_equal(matrix_to_quaternion(torch.eye(3)).numpy(), ident)
    q = np.array([0.5, -0.5, 0.5, 0.5])
    np.testing.assert_array_equal(quaternion_multiply(ident, q), q)
    np.testing.assert_array_equal(quaternion_multiply(q, ident), q)


def test_known_rotations():
    # 90 degrees about z: x -> y
    q = np.array([math.sqrt(0.5), 0, 0, math.sqrt(0.5)])
    np.testing.assert_allclose(quaternion_to_matrix(q), [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-15)
    np.testing.assert_allclose(matrix_to_quaternion(axis_angle([0, 0, 1], math.pi / 2)), q, atol=1e-15)
    # i * j = k
    i, j, k = np.eye(4)[1], np.eye(4)[2], np.eye(4)[3]
    np.testing.assert_array_equal(quaternion_multiply(i, j), k)
    np.testing.assert_array_equal(quaternion_multiply(j, i), -k)


def test_product_composes_rotation_matrices():
    R = random_rotations(200)
    qa, qb = matrix_to_quaternion(R[:100]), matrix_to_quaternion(R[100:])
    np.testing.assert_allclose(quaternion_to_matrix(quaternion_multiply(qa, qb)), R[:100] @ R[100:], atol=1e-12)
    ta, tb = torch.as_tensor(qa), torch.as_tensor(qb)
    np.testing.assert_array_equal(quaternion_multiply(ta, tb).numpy(), quaternion_multiply(qa, qb))


def test_round_trip_matrix_quaternion_matrix():
    R = random_rotations(1000, seed=1)
    q = matrix_to_quaternion(R)
    assert (q[:, 0] >= 0).all()
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1, atol=1e-15)
    np.testing.assert_allclose(quaternion_to_matrix(q), R, atol=1e-12)
    qt = matrix_to_quaternion(torch.as_tensor(R))
    assert qt.dtype == torch.float32  # the network's precision
    np.testing.assert_allclose(quaternion_to_matrix(qt).numpy(), R, atol=3e-5)


@pytest.mark.parametrize("axis", [[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, -1, 0], [0, 1, -1], [1, 2, -3], [-1, 0.5, 0.2]])
@pytest.mark.parametrize("angle", [math.pi, math.pi - 1e-9, math.pi - 1e-4, 2.5, -2.0])
def test_trace_at_or_below_zero_keeps_the_axis(axis, angle):
    """Rotations near 180 degrees (trace <= 0, w ~ 0): the signs come from the largest component, not from w (a wrong
    sign is an error of order 1). A component near zero comes from the square root of a difference of diagonal
    terms, so it carries about sqrt(eps): 1e-8 in float64, 1e-4 in float32 (the decoder network's precision)."""
    R = axis_angle(axis, angle)
    np.testing.assert_allclose(quaternion_to_matrix(matrix_to_quaternion(R)), R, atol=1e-7)
    np.testing.assert_allclose(quaternion_to_matrix(matrix_to_quaternion(torch.as_tensor(R))).numpy(), R, atol=5e-4)


def test_camera_facing_right_at_exactly_180_degrees():
    """camera_to_ego of a camera at yaw -90 (OpenCV axes into ego axes) is a rotation by exactly 180 degrees about
    (0, 1, -1) / sqrt(2): the differences m21 - m12 ... are all zero there."""
    R = np.array([[-1.0, 0, 0], [0, 0, -1], [0, -1, 0]])
    for q in (matrix_to_quaternion(R), matrix_to_quaternion(torch.as_tensor(R)).double().numpy()):
        np.testing.assert_allclose(quaternion_to_matrix(q), R, atol=1e-6)


def test_batch_shapes():
    R = random_rotations(12, seed=2).reshape(3, 4, 3, 3)
    assert matrix_to_quaternion(R).shape == (3, 4, 4)
    assert quaternion_to_matrix(matrix_to_quaternion(torch.as_tensor(R))).shape == (3, 4, 3, 3)


def test_normalize_quaternion_sign_and_near_zero():
    q = np.array([[2.0, 0, 0, 0], [-3.0, 0, 4, 0], [0, 0, 0, 0], [1e-8, 0, 0, 0], [0, -1e-7, 0, 0], [0, 2e-6, 0, 0]])
    out = normalize_quaternion(q, 1e-6)
    np.testing.assert_allclose(
        out, [[1, 0, 0, 0], [-0.6, 0, 0.8, 0], [1, 0, 0, 0], [1, 0, 0, 0], [1, 0, 0, 0], [0, 1, 0, 0]]
    )
    t = torch.as_tensor(q, dtype=torch.float64).requires_grad_()
    outt = normalize_quaternion(t, 1e-6)
    np.testing.assert_allclose(outt.detach().numpy(), out)
    outt.sum().backward()
    assert torch.isfinite(t.grad).all()  # the clamp keeps the gradient finite at q = 0


def test_pixel_rays_and_plucker():
    intr = torch.tensor([[10.0, 10.0, 2.0, 1.0]])
    c2w = torch.eye(4)[None].clone()
    c2w[0, :3, 3] = torch.tensor([1.0, 2.0, 3.0])
    o, d = pixel_rays(intr, c2w, (2, 4), (2, 4))
    assert o.shape == (1, 3) and d.shape == (1, 2, 4, 3)
    np.testing.assert_allclose(d[0, 0, 0].numpy(), [(0.5 - 2) / 10, (0.5 - 1) / 10, 1.0])
    assert (d[..., 2] == 1).all()  # unit camera-z: origin + depth * dir is at camera depth `depth`
    p = plucker(o, d, ray_scale=2.0)
    assert p.shape == (1, 6, 2, 4)
    dn = d / d.norm(dim=-1, keepdim=True)
    np.testing.assert_allclose(p[0, 3:].permute(1, 2, 0).numpy(), dn[0].numpy(), atol=1e-7)
    moment = torch.cross((o[0] / 2.0).expand_as(dn[0]), dn[0], dim=-1)
    np.testing.assert_allclose(p[0, :3].permute(1, 2, 0).numpy(), moment.numpy(), atol=1e-7)
