"""JointMap (names -> q) and JointStreamInterpolator (samples -> q(t), v(t)): policies and their messages."""
import numpy as np
import pytest

from clusterfem_ros.skeleton.joint_map import FATAL as MAP_FATAL
from clusterfem_ros.skeleton.joint_map import JointMap
from clusterfem_ros.skeleton.joint_stream import FATAL, JointStreamInterpolator, StaleSample

NAMES = ["root_x", "root_y", "yaw", "knee"]
REV = np.array([False, False, True, True])


def test_joint_map_keeps_last_values_reports_unknown_once_and_repairs_nan():
    jm = JointMap(NAMES, np.array([0.0, 0.0, 0.1, 0.2]))
    r = jm.update(["knee", "elbow"], [0.5, 9.0])
    assert r.accepted and r.new_unknown == ["elbow"] and r.v is None
    np.testing.assert_array_equal(r.q, [0.0, 0.0, 0.1, 0.5])
    assert r.updated.tolist() == [False, False, False, True]
    assert [k for k, _ in r.problems] == ["unknown_joint"] and "'elbow'" in r.problems[0][1]
    r = jm.update(["elbow", "yaw"], [1.0, -0.3])
    assert r.accepted and r.new_unknown == [] and r.problems == []          # reported once only
    np.testing.assert_array_equal(r.q, [0.0, 0.0, -0.3, 0.5])
    r = jm.update(["yaw", "knee"], [np.nan, 0.7])
    assert r.accepted and r.q[2] == -0.3 and r.q[3] == 0.7
    (kind, text), = r.problems
    assert kind == "non_finite" and "'yaw'" in text and "nan" in text


def test_joint_map_rejects_length_mismatch_duplicates_and_strangers():
    jm = JointMap(NAMES)
    r = jm.update(["yaw", "knee"], [0.1, 0.2, 0.3])
    assert not r.accepted and r.problems[0][0] == "length_mismatch" and "2 names but 3 positions" in r.problems[0][1]
    r = jm.update(["yaw", "yaw"], [0.1, 0.2])
    assert not r.accepted and r.problems[0][0] == "duplicate_joint" and "'yaw'" in r.problems[0][1]
    r = jm.update(["foo"], [1.0])
    assert not r.accepted and {k for k, _ in r.problems} == {"unknown_joint", "no_known_joint"}
    assert {"length_mismatch", "duplicate_joint", "no_known_joint"} <= MAP_FATAL
    np.testing.assert_array_equal(jm.q, np.zeros(4))                        # nothing leaked in


def test_joint_map_velocities_only_when_complete_and_finite():
    jm = JointMap(NAMES)
    r = jm.update(NAMES, [1, 2, 3, 4], [0.1, 0.2, 0.3, 0.4])
    np.testing.assert_array_equal(r.v, [0.1, 0.2, 0.3, 0.4])
    r = jm.update(["yaw"], [1.0], [0.5])
    assert r.accepted and r.v is None                                       # partial: derive instead
    r = jm.update(NAMES, [1, 2, 3, 4], [0.1, np.inf, 0.3, 0.4])
    assert r.accepted and r.v is None and r.problems[0][0] == "bad_velocity" and "'root_y'" in r.problems[0][1]


def stream(**kw):
    return JointStreamInterpolator(NAMES, revolute=REV, **kw)


def test_joint_map_follows_each_message_s_own_names_order_and_subset():
    """Messages change their names' order and subset from one to the next: each merges by its own names (the
    map keeps the last message's index arrays only while the names stay the same)."""
    rng = np.random.default_rng(5)
    jm = JointMap(NAMES)
    want = np.zeros(len(NAMES))
    for _ in range(40):
        order = list(rng.permutation(len(NAMES))[:rng.integers(1, len(NAMES) + 1)])
        names = [NAMES[i] for i in order] + (["stranger"] if rng.random() < 0.3 else [])
        pos = rng.standard_normal(len(names))
        vel = rng.standard_normal(len(names))
        res = jm.update(names, pos, vel)
        for k, i in enumerate(order):
            want[i] = pos[k]
        np.testing.assert_array_equal(res.q, want)
        assert res.accepted and res.updated.sum() == len(order)
        if len(order) == len(NAMES):                     # every joint named: the velocities, in skeleton order
            np.testing.assert_array_equal(res.v[order], vel[:len(order)])
        else:
            assert res.v is None


def test_interpolator_unwraps_angles_through_pi():
    s = stream()
    a0, a1 = np.deg2rad(179.0), np.deg2rad(-179.0)
    assert s.push(0.0, np.array([0, 0, a0, 0])) == []
    assert s.push(0.1, np.array([0, 0, a1, 0])) == []
    q, v = s.sample(0.05)
    np.testing.assert_allclose(np.cos(q[2]), -1.0, atol=1e-12)              # through 180 deg, not 0
    np.testing.assert_allclose(v[2], np.deg2rad(2.0) / 0.1, rtol=1e-12)


def test_interpolator_is_linear_between_samples_and_holds_outside():
    s = stream(horizon=0.02, teleport_distance=2.0)
    s.push(1.0, np.array([0.0, 0, 0, 0]))
    s.push(1.5, np.array([1.0, 0, 0, 0.5]))
    q, v = s.sample(1.2)
    np.testing.assert_allclose(q[[0, 3]], [0.4, 0.2])
    np.testing.assert_allclose(v[[0, 3]], [2.0, 1.0])
    q0, v0 = s.sample(0.0)
    np.testing.assert_array_equal(q0, np.zeros(4)) and np.testing.assert_array_equal(v0, 0)
    for late in (1.51, 1.52, 2.0, 100.0):                 # bounded: at most horizon * velocity past the newest
        q, v = s.sample(late)
        assert q[0] <= 1.0 + 0.02 * 2.0 + 1e-12
    np.testing.assert_allclose(s.sample(100.0)[0][0], 1.04)
    assert np.all(s.sample(100.0)[1] == 0)


def test_between_samples_the_velocity_is_the_poses_own_and_message_velocities_carry_it_on_after_the_newest():
    """Sparse samples of a fast swing (20 Hz: a player late on a loaded host) whose message velocities are the
    motion's at the sample instants, far from the segment's slope: the velocity sampled between them is the
    derivative of the pose sampled (the binding damps the flesh towards it; interpolated message velocities
    tore the cartwheel clip's toes through the node), and after the newest sample the message velocity moves
    the pose on for the horizon."""
    s = stream(max_future=2.0, horizon=0.02)
    w = 20.0                                               # a joint swinging at 20 rad/s peak
    for t in np.arange(0.0, 0.31, 0.05):
        s.push(float(t), np.array([0, 0, 0, np.sin(w * t)]), np.array([0, 0, 0, w * np.cos(w * t)]))
    for t in np.arange(0.012, 0.29, 0.02):                 # never at a sample, where the slope changes
        dt = 1e-6
        slope = (s.sample(t + dt)[0][3] - s.sample(t - dt)[0][3]) / (2 * dt)
        np.testing.assert_allclose(s.sample(t)[1][3], slope, rtol=1e-6, atol=1e-6)
    q_end, v_end = s.sample(0.3)[0][3], w * np.cos(w * 0.3)
    np.testing.assert_allclose(s.sample(0.31)[1][3], v_end, rtol=1e-12)
    np.testing.assert_allclose(s.sample(0.31)[0][3], q_end + 0.01 * v_end, rtol=1e-9)


def test_interpolator_rejects_out_of_order_stale_and_future_stamps():
    s = stream(max_age=1.0, max_future=0.5)
    s.push(10.0, np.zeros(4))
    kinds = [s.push(t, np.ones(4))[0][0] for t in (9.5, 10.0, 8.0, 11.0)]
    assert kinds == ["out_of_order", "out_of_order", "stale", "future"] and set(kinds) <= FATAL
    assert len(s) == 1 and s.newest == 10.0
    with pytest.raises(StaleSample, match="not newer") as e:
        s.push_or_raise(9.9, np.zeros(4))
    assert e.value.kind == "out_of_order"
    assert s.push(10.2, np.zeros(4)) == [] and s.newest == 10.2
    # with the receiver's clock the future check is absolute: a pause in the stream is no problem
    assert s.push(13.0, np.zeros(4), now=12.9) == [] and s.push(14.0, np.zeros(4), now=13.0)[0][0] == "future"


def test_a_restarted_stream_is_not_locked_out():
    s = stream(max_age=1.0, restart_after=3)
    s.push(100.0, np.zeros(4))
    out = [s.push(t, np.full(4, t)) for t in (0.0, 0.1, 0.2)]
    assert out[0][0][0] == "stale" and out[1][0][0] == "stale"
    assert [k for k, _ in out[2]] == ["stale", "restart"]
    assert s.newest == 0.2 and len(s) == 1                    # from the last of them: the one it stored
    np.testing.assert_allclose(s.sample(0.15)[0][0], 0.2)     # held before its first sample


def test_teleport_is_reported_and_not_interpolated_across():
    s = stream(teleport_distance=0.5)
    s.push(0.0, np.zeros(4))
    s.push(0.1, np.array([0.1, 0, 0, 0]))
    problems = s.push(0.2, np.array([5.0, 0, 0, 0]))
    assert [k for k, _ in problems] == ["teleport"] and "4.9" in problems[0][1]
    assert s.teleports == 1
    np.testing.assert_allclose(s.sample(0.15)[0][0], 5.0)                    # no sweep through the jump


def test_a_stalled_sender_resuming_its_walk_is_motion_not_a_teleport():
    """A player starved for 0.56 s on a loaded host resumes 0.56 m on (1 m/s): longer than teleport_distance, but a
    walk. It is interpolated across; the same jump in one 10 ms frame is a teleport."""
    s = stream(teleport_distance=0.5, teleport_speed=10.0)
    for k in range(5):
        assert s.push(0.01 * k, np.array([0.01 * k, 0, 0, 0])) == []
    assert s.push(0.6, np.array([0.6, 0, 0, 0]), now=0.6) == [] and s.teleports == 0   # the node's clock
    np.testing.assert_allclose(s.sample(0.3)[0][0], 0.3)                    # swept through, as walked
    problems = s.push(0.61, np.array([1.2, 0, 0, 0]), now=0.61)              # 0.6 m in 10 ms: 60 m/s
    assert [k for k, _ in problems] == ["teleport"] and "teleport_speed 10 m/s" in problems[0][1]
    with pytest.raises(ValueError, match="teleport_speed"):
        stream(teleport_speed=0.0)


def test_buffer_is_bounded_and_bad_samples_are_refused():
    s = stream(capacity=8)
    for k in range(50):
        s.push(k * 0.01, np.full(4, 0.001 * k))
    assert len(s) == 8
    (kind, text), = s.push(1.0, np.array([0, np.nan, 0, 0]))
    assert kind == "bad_sample" and "'root_y'" in text
    assert s.push(1.0, np.zeros(3))[0][0] == "bad_sample"
    with pytest.raises(RuntimeError, match="no joint sample yet"):
        stream().sample(0.0)


def _hostile_sequence(seed: int):
    """(stamp, q, v, now) of a 100 Hz stream with every kind of trouble mixed in: stale, out-of-order and future
    stamps, a run of stale stamps that restarts the stream backwards, a root far away, reported and measured
    speeds above the limit, a run of fast motion long enough to restart the stream, teleports, pauses."""
    rng = np.random.default_rng(seed)
    t, q, out = 100.0, np.zeros(4), []
    for k in range(400):
        t += 0.01 * (1 + (rng.random() < 0.05) * rng.integers(1, 80))       # now and then a pause
        q = q + rng.normal(0, 0.02, 4)
        what = rng.choice(["good"] * 12 + ["stale", "old", "future", "far", "v", "glitch", "teleport", "fast",
                                           "backwards"])
        if what == "stale":
            out.append((t - 5.0, q, None, t))
        elif what == "old":
            out.append((t - 0.02, q, None, t))
        elif what == "future":
            out.append((t + 5.0, q, None, t))
        elif what == "far":
            out.append((t, q + np.array([2e3, 0, 0, 0]), None, t))
        elif what == "v":
            out.append((t, q, np.array([0, 0, 0, 1e12]), t))
        elif what == "glitch":
            out.append((t, q + np.array([0, 0, 3.0, 0]), None, t))
        elif what == "teleport":
            q = q + np.array([0, 3.0, 0, 0])
            out.append((t, q, None, t))
        elif what == "fast":                           # 40 rad/s for 0.7 s: refused, then restarted on
            for _ in range(70):
                t += 0.01
                q = q + np.array([0, 0, 0, 0.4])
                out.append((t, q.copy(), None, t))
        else:                                          # a bag played again from its start: 4 old stamps in a row
            for j in range(4):
                out.append((t - 30.0 + 0.01 * j, q, None, t + 0.001 * j))
            t += 0.01
        if what != "teleport":
            out.append((t + 0.001, q.copy(), rng.normal(0, 1.0, 4) if rng.random() < 0.5 else None, t + 0.001))
            t += 0.001
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_samples_taken_in_pushed_again_as_taken_give_the_same_stream(seed):
    """What a recording replays: the node records only the samples its stream took in. Pushing those alone, in
    order and marked taken, must give after each one the same problems, the same stored samples and the same
    interpolated pose as the stream that also saw (and refused) the others."""
    kw = dict(max_age=0.5, max_future=0.5, teleport_distance=0.5, max_root_distance=1000.0, max_joint_speed=30.0)
    live, again = stream(**kw), stream(**kw)
    taken = refused = restarts = 0
    for stamp, q, v, now in _hostile_sequence(seed):
        problems = live.push(stamp, q, v, now=now)
        if not live.took_last:
            refused += 1
            continue
        taken += 1
        restarts += any(k == "restart" for k, _ in problems)
        again_problems = again.push(stamp, q, v, now=now, taken=True)
        assert again.took_last and [k for k, _ in again_problems] == [k for k, _ in problems], (stamp, problems)
        assert list(again._t) == list(live._t)
        assert all(np.array_equal(a, b) for a, b in zip(again._q, live._q))
        for t in (stamp - 0.013, stamp, stamp + 0.004):
            ql, vl = live.sample(t)
            qa, va = again.sample(t)
            assert np.array_equal(ql, qa) and np.array_equal(vl, va)
    assert taken > 300 and refused > 40 and restarts >= 2           # every path was taken, not just the easy one


def test_a_refused_sample_leaves_the_joint_map_as_it_was():
    """A joint map keeps the values of the samples taken in only (merge, then commit): a split publisher's next
    partial message is merged into the last sample taken in, never into one the stream refused."""
    jm = JointMap(NAMES)
    r = jm.merge(["root_x", "yaw"], [1e9, 0.3])                      # a root 1e9 m away: the stream refuses it
    assert r.accepted and r.q[0] == 1e9
    np.testing.assert_array_equal(jm.q, np.zeros(4))
    r = jm.merge(["knee"], [0.4])                                     # the other publisher's half
    np.testing.assert_array_equal(r.q, [0.0, 0.0, 0.0, 0.4])
    jm.commit(r.q)
    np.testing.assert_array_equal(jm.merge(["yaw"], [0.1]).q, [0.0, 0.0, 0.1, 0.4])


def test_a_restart_waits_for_a_sample_in_range_and_keeps_no_growing_list():
    """Old stamps in a row restart the stream only on one whose root is in range; the thousands refused before it
    leave a bounded memory."""
    s = stream(max_age=1.0, restart_after=3, max_root_distance=10.0)
    s.push(100.0, np.zeros(4))
    for k in range(5000):
        kinds = [kind for kind, _ in s.push(0.001 * k, np.array([50.0, 0, 0, 0]))]
        assert kinds[0] == "stale" and "restart" not in kinds and not s.took_last
    assert len(s._rejected) <= 3 and s.newest == 100.0
    assert [kind for kind, _ in s.push(6.0, np.array([5.0, 0, 0, 0]))] == ["stale", "restart"]
    assert s.took_last and s.newest == 6.0 and len(s) == 1
