"""Print orientation (skelfem/fabricate/orientation.py): every part lies flat on a face, whichever way that
face points in the design; parts of the bundled designs are in test_fabricate.py."""
import numpy as np
import pytest

from skelfem.fabricate.orientation import DIRECTIONS, best_pose, planar_faces, pose, rotation_putting_down


def prism(base: np.ndarray, length: float) -> tuple[np.ndarray, np.ndarray]:
    """A right prism over a convex counter-clockwise polygon in z = 0, up to z = length: (points, triangles
    with outward normals)."""
    k = len(base)
    points = np.vstack([np.column_stack([base, np.zeros(k)]), np.column_stack([base, np.full(k, length)])])
    tris = [[0, i + 1, i] for i in range(1, k - 1)] + [[k, k + i, k + i + 1] for i in range(1, k - 1)]
    for i in range(k):
        j = (i + 1) % k
        tris += [[i, j, k + j], [i, k + j, k + i]]
    return points, np.array(tris)


def turned(points: np.ndarray, axis, angle: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation
    return points @ Rotation.from_rotvec(angle * np.asarray(axis, float) / np.linalg.norm(axis)).as_matrix().T


# a triangular prism, 30 mm long, its sides 12 (the largest face: 12 x 30), 10 and 8 mm wide
TRIANGLE = np.array([[0.0, 0.0], [12.0, 0.0], [4.5, 6.0]])
SIDES = [12.0, float(np.hypot(7.5, 6.0)), float(np.hypot(4.5, 6.0))]


def test_a_tilted_prism_lies_on_its_largest_side():
    """Turned off every axis, the prism touches the bed in one corner in each of the six axis directions;
    its faces are found whichever way they point, and it lies on its widest side with nothing overhanging."""
    points, tris = prism(TRIANGLE, 30.0)
    points = turned(points, [1.0, 2.0, 3.0], 0.7) + [5.0, -3.0, 8.0]
    assert all(pose(points, tris, d).bed_area == 0.0 for d in DIRECTIONS)       # the axes alone: on a corner
    faces = planar_faces(points, tris)
    assert sorted(a for _, a in faces) == pytest.approx(sorted([36.0, 36.0] + [30 * s for s in SIDES]))
    best = best_pose(points, tris)
    assert best.bed_area == pytest.approx(12.0 * 30.0) and best.support_area == pytest.approx(0.0, abs=1e-9)
    assert best.down not in DIRECTIONS and best.down.startswith("(")
    printed = best.apply(points)
    assert printed[:, 2].min() == pytest.approx(0.0, abs=1e-9)
    on_bed = np.abs(printed[:, 2]) < 1e-9
    assert on_bed.sum() == 4                                   # the side's four corners, no other
    assert best.rotation @ best.direction == pytest.approx([0.0, 0.0, -1.0], abs=1e-12)
    assert np.linalg.det(best.rotation) == pytest.approx(1.0) and best.rotation @ best.rotation.T == \
        pytest.approx(np.eye(3), abs=1e-12)


def test_a_face_in_a_recess_is_no_bed():
    """An L-shaped prism: the inner face of the L (15 x 10 at y = 5) points the way of the outer one at the
    tip of its upright (5 x 10 at y = 20) but lies inside, so it cannot touch the bed: it is no candidate,
    and the outer one is, with its own area."""
    L = np.array([[0, 0], [20, 0], [20, 5], [5, 5], [5, 20], [0, 20]], float)
    # the L is not convex: triangulate its caps by a fan from corner 3, which sees every other corner
    points, _ = prism(L, 10.0)
    k = len(L)
    order = [3, 4, 5, 0, 1, 2]
    fan = [[order[0], order[i + 1], order[i]] for i in range(1, k - 1)]
    tris = np.array(fan + [[k + a, k + c, k + b] for a, b, c in fan]
                    + [t for i in range(k) for t in ([i, (i + 1) % k, k + (i + 1) % k], [i, k + (i + 1) % k, k + i])])
    points = turned(points, [0.3, -1.0, 0.2], 0.5)
    normal = turned(np.array([[0.0, 1.0, 0.0]]), [0.3, -1.0, 0.2], 0.5)[0]
    along = [a for d, a in planar_faces(points, tris) if np.allclose(d, normal, atol=1e-6)]
    assert along == [pytest.approx(5.0 * 10.0)]
    assert best_pose(points, tris).bed_area > 0


def test_the_axis_turns_are_exact():
    """An axis direction keeps its rotation exact in zeros and ones (the parts of the bundled designs are
    boxes and extrusions whose coordinates stay as drawn)."""
    for d in DIRECTIONS:
        R = rotation_putting_down(d)
        assert np.all(np.isin(R, [-1.0, 0.0, 1.0])) and np.linalg.det(R) == 1.0
