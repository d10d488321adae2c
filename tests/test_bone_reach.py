"""An end bone's segment carried on into its flesh (body/bone_reach.py): which bones, how far, and what it
changes in a binding."""
import numpy as np
import pytest

trimesh = pytest.importorskip("trimesh")

from clusterfem_ros.body.binding import bind_to_skeleton
from clusterfem_ros.body.bone_reach import describe, end_bones, reach_to_skin


def _box(extents, centre=(0.0, 0.0, 0.0)):
    m = trimesh.creation.box(extents=extents)
    return m.vertices + np.asarray(centre), m.faces


def test_end_bones_are_the_binding_bones_without_a_binding_descendant():
    #        0 pelvis
    #       / \
    #      1   3 spine -> 4 head -> 5 head side part (bare)
    #      |
    #      2 hand -> 6 finger (bare), 7 finger (bare)
    parent = np.array([-1, 0, 1, 0, 3, 4, 2, 2])
    binds = np.array([True, True, True, True, True, False, False, False])
    assert end_bones(parent, binds).tolist() == [False, False, True, False, True, False, False, False]
    binds[6] = True                       # a finger that binds: the hand is no end bone, the finger is
    assert end_bones(parent, binds).tolist() == [False, False, False, False, True, False, True, False]
    assert end_bones(parent, np.ones(8, bool)).tolist() == [False, False, False, False, False, True, True, True]


def test_an_end_bone_reaches_its_tip_less_the_depth_of_its_end_and_the_others_keep_theirs():
    """A 0.2 x 0.2 x 1.0 m box around the z axis: a bone ending at z = 0.1, 0.1 m under the sides, reaches
    z = 0.5 - 0.1; the same bone not chosen, a zero-length one and one whose end lies outside keep their ends."""
    v, f = _box((0.2, 0.2, 1.0))
    starts = np.array([[0, 0, -0.2], [0, 0, -0.2], [0.05, 0, 0.0], [0, 0, 0.0]], float)
    ends = np.array([[0, 0, 0.1], [0, 0, 0.1], [0.05, 0, 0.0], [0, 0, 0.7]], float)
    out, reach, turn = reach_to_skin(starts, ends, np.array([True, False, True, True]), v, f)
    np.testing.assert_allclose(out[0], [0, 0, 0.4], atol=1e-12)
    assert reach[0] == pytest.approx(0.3, abs=1e-12)
    np.testing.assert_array_equal(out[1:], ends[1:])
    assert reach[1:].tolist() == [0.0, 0.0, 0.0]
    assert turn.tolist() == [0.0, 0.0, 0.0, 0.0]
    line = describe(["shin", "thigh", "dot", "out"], reach, turn)
    assert line.endswith(": shin +30.0 cm")


def test_a_slanted_end_bone_runs_on_along_its_own_direction():
    """A unit cube, a bone from its centre along (2, 1, 0): it leaves through the face x = 0.5, and its end then
    lies as deep under that point as its own end lay under the nearest face."""
    v, f = _box((1.0, 1.0, 1.0))
    d = np.array([2.0, 1.0, 0.0]) / np.sqrt(5.0)
    starts, ends = np.zeros((1, 3)), 0.1 * d[None]
    out, reach, turn = reach_to_skin(starts, ends, np.array([True]), v, f)
    exit_at, depth = 0.5 / d[0], 0.5 - 0.1 * d[0]
    np.testing.assert_allclose(out[0], (exit_at - depth) * d, atol=1e-12)
    assert reach[0] == pytest.approx(exit_at - depth - 0.1, abs=1e-12)


def test_the_flesh_past_a_short_end_bone_binds_to_its_reach():
    """Vertices of a tall box over a short end bone: bound to the bone's plain segment, the top lies 0.4 m from
    it; to its reach, 0.1 m (the depth of the sides), and more of the body is in the innermost level."""
    v, f = _box((0.2, 0.2, 1.0), centre=(0, 0, 0.3))       # z from -0.2 to 0.8
    grid = np.stack(np.meshgrid(np.linspace(-0.1, 0.1, 5), np.linspace(-0.1, 0.1, 5),
                                np.linspace(-0.2, 0.8, 21), indexing="ij"), -1).reshape(-1, 3)
    starts, ends = np.array([[0, 0, -0.2]]), np.array([[0, 0, 0.3]])
    reached, _, _ = reach_to_skin(starts, ends, np.array([True]), v, f)
    plain = bind_to_skeleton(grid, starts, ends, [0.05, 0.5], warn=False)
    carried = bind_to_skeleton(grid, starts, reached, [0.05, 0.5], warn=False)
    top = grid[:, 2] > 0.79
    assert plain.distance[top].max() == pytest.approx(np.hypot(0.5, np.hypot(0.1, 0.1)), rel=1e-9)
    assert carried.distance[top].max() == pytest.approx(np.hypot(0.1, np.hypot(0.1, 0.1)), rel=1e-9)
    assert (carried.level == 0).sum() > (plain.level == 0).sum()


def test_an_end_bone_at_the_back_of_its_flesh_is_aimed_through_the_flesh_s_centre():
    """A 'head': a 0.3 m cube whose centre is 0.1 m in front of (+x) and 0.14 m above a head joint near its back
    face; the bone points straight up. Aimed through the centre of the cube's points, the
    segment runs from the joint through the centre on to as deep under the skin as the centre lies (0.15 m): the
    farthest point of the cube comes a quarter nearer to it than to the plain bone (0.35 m)."""
    v, f = _box((0.3, 0.3, 0.3), centre=(0.1, 0.0, 0.15))
    grid = np.stack(np.meshgrid(*[np.linspace(-0.15, 0.15, 7)] * 3, indexing="ij"), -1).reshape(-1, 3) + [0.1, 0, 0.15]
    starts, ends = np.array([[0.0, 0.0, 0.01]]), np.array([[0.0, 0.0, 0.1]])
    flesh = (grid, np.ones(len(grid)), np.zeros(len(grid), dtype=np.int64))
    out, reach, turn = reach_to_skin(starts, ends, np.array([True]), v, f, flesh=flesh)
    centre = np.array([0.1, 0.0, 0.15])
    d = (centre - starts[0]) / np.linalg.norm(centre - starts[0])
    np.testing.assert_allclose(np.cross(out[0] - starts[0], d), 0.0, atol=1e-12)      # on the line through the centre
    assert np.linalg.norm(out[0] - centre) == pytest.approx(_exit(centre, d, 0.15, (0.1, 0.0, 0.15)) - 0.15, abs=1e-9)
    assert turn[0] == pytest.approx(np.degrees(np.arccos(d[2])), abs=1e-9)
    plain = bind_to_skeleton(grid, starts, ends, [0.5], warn=False)
    aimed = bind_to_skeleton(grid, starts, out, [0.5], warn=False)
    assert plain.distance.max() > 0.35 and aimed.distance.max() < 0.75 * plain.distance.max()
    # a bone longer than its flesh's centre is deep keeps its direction: a finger-less hand, a foot
    long_ends = np.array([[0.0, 0.0, 0.2]])
    straight, _, turned = reach_to_skin(starts, long_ends, np.array([True]), v, f, flesh=flesh)
    assert turned[0] == 0.0 and np.abs(straight[0, :2]).max() < 1e-12 and straight[0, 2] > 0.2
    # flesh whose centre is behind the start keeps the bone's own direction (and so its plain reach)
    behind = (grid - [0, 0, 0.5], np.ones(len(grid)), np.zeros(len(grid), dtype=np.int64))
    kept, _, turned = reach_to_skin(starts, ends, np.array([True]), v, f, flesh=behind)
    assert turned[0] == 0.0 and np.cross(kept[0] - starts[0], [0, 0, 1]).max() < 1e-12


def _exit(p, d, half, centre):
    """How far the ray p + t d goes to leave the axis-aligned cube of half-width ``half`` about ``centre``."""
    lo, hi = np.asarray(centre) - half, np.asarray(centre) + half
    t = [((hi[i] if d[i] > 0 else lo[i]) - p[i]) / d[i] for i in range(3) if abs(d[i]) > 1e-15]
    return min(t)
