"""Primitives: outward unit normals, CCW winding, extents, uv scale, input checks."""
import numpy as np
import pytest

from scenes.model import Mesh
from scenes.primitives import box, cone, cylinder, gable_roof, ground_strip, pose_2d, quad, sphere_low, sweep


def _tri(m: Mesh):
    return m.positions[m.indices.astype(np.int64)].astype(np.float64)  # (M, 3, 3)


def _check_mesh(m: Mesh, closed_center=None):
    assert m.positions.dtype == np.float32 and m.normals.dtype == np.float32
    assert m.uvs.dtype == np.float32 and m.layers.dtype == np.int32 and m.tints.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(m.normals, axis=1), 1.0, atol=1e-5)
    p = _tri(m)
    geo_n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    vert_n = m.normals[m.indices[:, 0]]
    # winding CCW seen from the side the normal points to
    assert np.all(np.sum(geo_n * vert_n, axis=1) > 0)
    # flat shading: every vertex of a triangle carries the face normal
    for k in range(3):
        np.testing.assert_allclose(m.normals[m.indices[:, k]], geo_n / np.linalg.norm(geo_n, axis=1, keepdims=True), atol=1e-4)
    if closed_center is not None:
        out = np.sum((p.mean(1) - closed_center) * vert_n, axis=1)
        assert np.all(out > 0), "normals must point away from the centre of a convex solid"


def test_box_normals_winding_extent():
    m = box((2.0, 3.0, 4.0), 5, tint=(0.5, 0.6, 0.7))
    assert m.n_triangles == 12 and m.n_vertices == 24
    _check_mesh(m, closed_center=np.zeros(3))
    np.testing.assert_allclose(m.positions.min(0), [-1, -1.5, -2])
    np.testing.assert_allclose(m.positions.max(0), [1, 1.5, 2])
    assert np.all(m.layers == 5)
    np.testing.assert_allclose(m.tints, np.tile([0.5, 0.6, 0.7], (24, 1)), atol=1e-6)


def test_box_transform_and_uv_scale():
    T = pose_2d(10.0, -4.0, np.pi / 2, 3.0)
    m = box((2.0, 4.0, 6.0), 0, T=T, uv_scale=(0.5, 0.25))
    _check_mesh(m, closed_center=np.array([10.0, -4.0, 3.0]))
    np.testing.assert_allclose(m.positions.min(0), [8.0, -5.0, 0.0], atol=1e-5)
    np.testing.assert_allclose(m.positions.max(0), [12.0, -3.0, 6.0], atol=1e-5)
    # vertical faces: u spans width * su, v spans -height * sv, starting at 0 at the bottom edge
    vert = np.abs(m.normals[:, 2]) < 0.5
    assert np.isclose(m.uvs[vert, 1].min(), -6.0 * 0.25) and np.isclose(m.uvs[vert, 1].max(), 0.0)
    assert np.isclose(m.uvs[vert, 0].min(), 0.0) and np.isclose(m.uvs[vert, 0].max(), 4.0 * 0.5)


def test_box_faces_subset_and_errors():
    m = box((1.0, 1.0, 1.0), 0, faces="+x-x+y-y+z")
    assert m.n_triangles == 10 and np.all(m.normals[:, 2] > -0.5)
    with pytest.raises(ValueError, match="size_xyz"):
        box((1.0, -1.0, 1.0), 0)
    with pytest.raises(ValueError, match="layer"):
        box((1.0, 1.0, 1.0), -1)
    with pytest.raises(ValueError, match="tint"):
        box((1.0, 1.0, 1.0), 0, tint=(1.0, 1.0))
    with pytest.raises(ValueError, match="T must be"):
        box((1.0, 1.0, 1.0), 0, T=np.eye(3))
    with pytest.raises(ValueError, match="rigid"):
        box((1.0, 1.0, 1.0), 0, T=np.diag([2.0, 1.0, 1.0, 1.0]))
    with pytest.raises(ValueError, match="faces"):
        box((1.0, 1.0, 1.0), 0, faces="+w")


@pytest.mark.parametrize("make,center", [
    (lambda: cylinder(1.0, 2.0, 0, 12), np.array([0, 0, 1.0])),
    (lambda: cone(1.0, 2.0, 0, 8), np.array([0, 0, 0.5])),
    (lambda: sphere_low((1.0, 2.0, 1.5), 0, 8, 5), np.zeros(3)),
])
def test_round_solids(make, center):
    m = make()
    _check_mesh(m, closed_center=center)


def test_cylinder_extent():
    m = cylinder(0.5, 3.0, 2, 16)
    assert np.isclose(m.positions[:, 2].min(), 0.0) and np.isclose(m.positions[:, 2].max(), 3.0)
    assert np.linalg.norm(m.positions[:, :2], axis=1).max() <= 0.5 + 1e-6
    with pytest.raises(ValueError, match="segments"):
        cylinder(0.5, 3.0, 2, 2)
    with pytest.raises(ValueError, match="radius"):
        cylinder(0.0, 3.0, 2)


def test_quad_normal_and_double_sided():
    c = np.array([[0, 0, 0], [2, 0, 0], [2, 0, 1], [0, 0, 1]], dtype=np.float64)  # CCW seen from -y
    m = quad(c, 3)
    _check_mesh(m)
    np.testing.assert_allclose(m.normals[0], [0, -1, 0], atol=1e-6)
    m2 = quad(c, 3, double_sided=True)
    assert m2.n_triangles == 4
    _check_mesh(m2)
    with pytest.raises(ValueError, match="corners"):
        quad(np.zeros((3, 3)), 0)


def test_ground_strip_area_normals_uv():
    line = np.array([[0.0, 0.0], [10.0, 0.0], [25.0, 0.0]])
    m = ground_strip(line, 1.5, 0.01, 1, uv_scale=0.5)
    _check_mesh(m)
    np.testing.assert_allclose(m.normals, np.tile([0, 0, 1], (m.n_vertices, 1)))
    p = _tri(m)
    area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1).sum()
    assert np.isclose(area, 25.0 * 3.0, rtol=1e-5)
    assert np.allclose(m.positions[:, 2], 0.01)
    assert np.isclose(m.uvs[:, 0].max(), 12.5) and np.isclose(m.uvs[:, 1].max(), 1.5)


def test_ground_strip_curve_ccw_from_above_and_offset():
    a = np.linspace(0, np.pi / 2, 20)
    arc = np.stack([20 * np.sin(a), 20 - 20 * np.cos(a)], 1)  # left turn, radius 20
    m = ground_strip(arc, 1.0, 0.0, 0, lateral_offset=-3.0)
    p = _tri(m)
    assert np.all(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])[:, 2] > 0)
    r = np.linalg.norm(m.positions[:, :2] - [0.0, 20.0], axis=1)
    assert r.min() > 21.9 and r.max() < 24.1  # radius 20 + 3 +- 1 (mitred)
    with pytest.raises(ValueError, match="polyline"):
        ground_strip(np.zeros((1, 2)), 1.0, 0.0, 0)
    with pytest.raises(ValueError, match="half_width"):
        ground_strip(arc, 0.0, 0.0, 0)


def test_sweep_kerb_faces_road():
    line = np.array([[0.0, 0.0], [20.0, 0.0]])
    # right-hand kerb + sidewalk, outline counter-clockwise: the kerb face looks at the road (+y)
    m = sweep(line, np.array([[-3.5, 0.0], [-3.5, 0.15], [-6.5, 0.15], [-6.5, 0.0]]), 0)
    _check_mesh(m)
    kerb = np.isclose(m.positions[:, 1], -3.5) & np.isclose(m.normals[:, 2], 0.0)
    assert np.all(m.normals[kerb, 1] > 0.99)
    top = np.isclose(m.positions[:, 2], 0.15) & (m.normals[:, 2] > 0.5)
    assert top.sum() >= 4


def test_gable_roof():
    m = gable_roof((8.0, 6.0), 2.0, 1, 2, overhang=0.0)
    _check_mesh(m)
    assert np.isclose(m.positions[:, 2].max(), 2.0)
    assert set(np.unique(m.layers)) == {1, 2}
