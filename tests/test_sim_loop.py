"""The physics thread (sim_loop.SimLoop), without ROS: input-clock determinism against the stepping it replaced,
snapshots that are never written after hand-over, failures reported and survived, latency bookkeeping."""
import threading
import time
from collections import deque

import numpy as np
import pytest

from clusterfem_ros.config import SceneConfig
from clusterfem_ros.motion import load_motion
from clusterfem_ros.scene import Scene
from clusterfem_ros.sim_loop import INPUT_QUEUE, MAX_CRASHES_IN_A_ROW, LatencyMeter, SimLoop, StageClock

SMALL_MAN = dict(body__target_tets=700, warping=True)
INPUT_CLOCK = dict(SMALL_MAN, physics__clock="input")
T0 = 1000.0                                   # stamps far from zero, as on a ROS clock


def _samples(seconds, rate=120.0, offset=0.0):
    m = load_motion()
    for k in range(int(seconds * rate)):
        q, v = m.trajectory.sample(offset + k / rate, loop=True)
        yield T0 + k / rate, m.trajectory.names, q, v


def _wait_for(predicate, timeout=30.0, what="condition"):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return
        time.sleep(0.005)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


class _Log(list):
    def __call__(self, level, text):
        self.append((level, text))


def _loop(scene, now=lambda: 0.0, **kw):
    """A loop on the scene's physics.clock."""
    log = _Log()
    loop = SimLoop(scene, now, kw.pop("timer_hz", 100.0), kw.pop("max_catchup_steps", 250), log)
    return loop, log


def test_input_clock_on_the_thread_gives_the_states_of_push_then_follow_bit_for_bit():
    config = SceneConfig().with_values(**INPUT_CLOCK)
    direct, threaded = Scene.build(config), Scene.build(config)
    expected = {}
    for stamp, names, q, v in _samples(0.5):              # what the node did on its executor thread
        direct.push_joint_state(stamp, names, q, v, now=stamp)
        direct.follow_inputs(250)
        expected[direct.steps_done] = direct.positions().copy()
    loop, log = _loop(threaded)
    seen = {}
    loop.start()
    try:
        for stamp, names, q, v in _samples(0.5):
            loop.take_input(lambda s=stamp, n=names, q=q, v=v: threaded.take_joint_state(s, n, q, v, received=s))
            snap = loop.snapshot
            if snap is not None:
                seen[snap.steps] = threaded.model.rest + snap.u
        _wait_for(lambda: loop.snapshot is not None and loop.snapshot.steps == direct.steps_done, 60, "all steps")
    finally:
        assert loop.stop()
    snap = loop.snapshot
    seen[snap.steps] = threaded.model.rest + snap.u
    assert threaded.steps_done == direct.steps_done > 400 and log == []
    assert np.array_equal(threaded.positions(), direct.positions())
    for steps, x in seen.items():                   # every state handed over is one the old stepping had
        assert np.array_equal(x, expected[steps]), steps
    assert snap.sim_time == direct.sim_time and snap.inputs_used == direct.inputs.accepted


def test_a_snapshot_is_never_written_after_it_is_handed_over():
    scene = Scene.build(SceneConfig().with_values(**INPUT_CLOCK))
    loop, _ = _loop(scene)
    loop.start()
    try:
        samples = list(_samples(0.4))
        for stamp, names, q, v in samples[:10]:
            loop.take_input(lambda s=stamp, n=names, q=q, v=v: scene.take_joint_state(s, n, q, v, received=s))
        _wait_for(lambda: loop.snapshot is not None and loop.snapshot.steps > 0, 30, "a snapshot")
        first = loop.snapshot
        kept = first.u.copy(), first.v.copy()
        with pytest.raises(ValueError):
            first.u[0, 0] = 1.0                                 # read-only: no output can scribble on it
        for stamp, names, q, v in samples[10:]:
            loop.take_input(lambda s=stamp, n=names, q=q, v=v: scene.take_joint_state(s, n, q, v, received=s))
        _wait_for(lambda: loop.snapshot.steps > first.steps + 200, 30, "200 more steps")
    finally:
        assert loop.stop()
    assert np.array_equal(first.u, kept[0]) and np.array_equal(first.v, kept[1])
    assert not np.array_equal(loop.snapshot.u, first.u)         # the body moved on, in other arrays


def test_nothing_is_handed_over_before_a_joint_state_places_the_body():
    scene = Scene.build(SceneConfig().with_values(**SMALL_MAN, physics__input_wait=0.25))
    clock = {"now": T0}
    loop, log = _loop(scene, now=lambda: clock["now"])
    loop.start()
    try:
        _wait_for(lambda: scene.sim_time is not None, 10, "the wall clock to start the scene")
        _wait_for(lambda: loop.unpublishable > 0, 10, "a state refused before any joint state")
        assert loop.snapshot is None                      # the body stands at the neutral pose, not on the clip
        stamp, names, q, v = next(_samples(0.1))
        loop.take_input(lambda: scene.take_joint_state(T0, names, q, v, received=T0))
        clock["now"] = T0 + 1.5 * scene.h                 # physics waits at the newest sample (physics.input_wait)
        time.sleep(0.1)
        assert loop.snapshot is None and scene.sim_time == T0
        t1 = T0 + 1.5 * scene.h                           # one step due: it puts the body on the samples' pose
        loop.take_input(lambda: scene.take_joint_state(t1, names, q, v, received=t1))
        _wait_for(lambda: loop.snapshot is not None, 10, "the placed body's snapshot")
    finally:
        assert loop.stop()
    assert loop.snapshot.steps == 1 and scene.placed and log == []


def test_wall_clock_follows_the_clock_and_counts_the_stages():
    scene = Scene.build(SceneConfig().with_values(body__kind="sphere", skeleton__source="none", warping=False))
    t_start = time.perf_counter()
    loop, log = _loop(scene, now=lambda: time.perf_counter() - t_start)
    loop.start()
    try:
        _wait_for(lambda: scene.sim_time is not None and scene.sim_time > 0.2, 30, "0.2 s of physics")
    finally:
        assert loop.stop()
    t_end = time.perf_counter() - t_start
    assert scene.sim_time <= t_end + 1e-9                          # never ahead of the clock
    assert loop.stages.totals["physics"] > 0 and loop.stages.totals["skeleton"] > 0
    assert loop.stages.totals["physics"] + loop.stages.totals["skeleton"] == pytest.approx(scene.step_wall_s)
    staged = sum(loop.stages.totals[k] for k in ("inputs", "skeleton", "physics", "checks", "snapshot"))
    assert loop.stages.totals["snapshot"] > 0 and loop.stages.totals["checks"] > 0 and staged > scene.step_wall_s
    busy = loop.busy_s()                       # the thread's time outside its waits: its stages and their glue
    assert staged <= busy < t_end
    cpu = loop.cpu_s()                         # no other thread wants the GIL here: CPU time is most of it
    # the thread's CPU clock and the wall clock are read at slightly different instants around every wait, and a
    # loaded VM's CPU clock can run a little ahead of the wall clock over such a short run: 5 ms of slack; the
    # waits' own time counted in would add the run's idle seconds
    assert 0 < cpu <= busy * 1.01 + 0.005
    room = loop.headroom()
    assert room["in_node"] == pytest.approx(scene.steps_done * scene.h / busy)
    assert room["alone"] == pytest.approx(scene.steps_done * scene.h / cpu) and room["alone"] >= room["in_node"] * 0.95
    assert log == []


def _run_past_a_failure(scene, what: str):
    """(loop, log): ``scene`` on the wall clock until it has made 100 steps (a failure injected at step 30 and
    what the loop did about it behind them), then stopped."""
    t_start = time.perf_counter()
    loop, log = _loop(scene, now=lambda: time.perf_counter() - t_start)
    loop.start()
    try:
        _wait_for(lambda: scene.steps_done > 100, 30, what)
    finally:
        assert loop.stop()
    return loop, log


def test_a_failing_step_is_reported_the_body_reset_and_physics_goes_on():
    scene = Scene.build(SceneConfig().with_values(body__kind="sphere", skeleton__source="none", warping=False))
    real_step = scene.integrator.step
    failures = {"left": 1}

    def step(*args):
        if failures["left"] and scene.steps_done >= 30:
            failures["left"] -= 1
            raise RuntimeError("injected failure")
        return real_step(*args)

    scene.integrator.step = step
    loop, log = _run_past_a_failure(scene, "steps after the failure")
    assert loop.crashes == 1 and not loop.stopped and "injected failure" in loop.error
    assert [lvl for lvl, _ in log] == ["error"] and "RuntimeError" in log[0][1] and "reset" in log[0][1]


def test_a_divergence_whose_reset_fails_too_is_a_failure_and_physics_goes_on():
    """A divergence resets the body; a reset that raises as well (a character's placement its step plan refuses)
    is counted as a failure and reset again, never the end of the thread."""
    from clusterfem_ros.fem.stability import DivergenceError, StabilityError
    scene = Scene.build(SceneConfig().with_values(body__kind="sphere", skeleton__source="none", warping=False))
    real_step, real_reset = scene.integrator.step, scene.reset
    left = {"step": 1, "reset": 1}

    def step(*args):
        if left["step"] and scene.steps_done >= 30:
            left["step"] -= 1
            raise DivergenceError("injected divergence")
        return real_step(*args)

    def reset():
        if left["reset"]:
            left["reset"] -= 1
            raise StabilityError("injected refusal of the placement")
        real_reset()

    scene.integrator.step, scene.reset = step, reset
    loop, log = _run_past_a_failure(scene, "steps after the failed reset")
    assert loop.divergences == 1 and loop.crashes == 1 and not loop.stopped and left == {"step": 0, "reset": 0}
    assert "injected refusal" in loop.error and [lvl for lvl, _ in log] == ["error", "error"]


def test_failures_in_a_row_stop_the_thread_and_stop_still_returns():
    scene = Scene.build(SceneConfig().with_values(body__kind="sphere", skeleton__source="none", warping=False))

    def step(*args):
        raise FloatingPointError("always")

    scene.integrator.step = step
    loop, log = _loop(scene, now=lambda: time.perf_counter())
    loop.start()
    _wait_for(lambda: not loop.running, 10, "the thread to give up")
    assert loop.stopped and loop.crashes == MAX_CRASHES_IN_A_ROW
    assert "stopped" in log[-1][1] and loop.stop(timeout=1.0)


def test_latency_closes_every_arrival_seen_by_the_published_state():
    meter = LatencyMeter(keep=100)
    for seq, t in enumerate([1.000, 1.010, 1.020, 1.030], start=1):
        meter.arrived(seq, t)
    meter.handed_over(2, 1.025)                 # a snapshot that had seen the first two
    meter.published(2, 1.040)                   # a marker of it
    meter.published(2, 1.070)                   # the same state again: nothing new to close
    meter.handed_over(4, 1.035)
    meter.handed_over(4, 1.045)                 # a later snapshot: the first one closed them
    meter.published(4, 1.050)
    assert meter.count == 4
    assert meter.max == pytest.approx(0.040)
    p = meter.percentiles()
    assert p["latency_max_ms"] == pytest.approx(40.0)
    assert p["latency_p50_ms"] == pytest.approx(np.percentile([40, 30, 30, 20], 50))
    assert p["latency_state_p99_ms"] == pytest.approx(np.percentile([25, 15, 15, 5], 99))


def test_stage_shares_are_seconds_per_wall_second():
    clock = StageClock()
    time.sleep(0.05)                                  # the window is at least this long
    clock.add("markers", 0.01)
    other = threading.Thread(target=lambda: clock.add("physics", 0.02))   # a stage added to from its own thread
    other.start()
    other.join()
    s = clock.shares()
    assert 0 < s["markers"] < s["physics"] <= 0.02 / 0.05 + 1e-9
    assert s["physics"] == pytest.approx(2 * s["markers"])
    assert clock.shares()["markers"] == 0.0           # a new window


STEP_COST = 0.1e-3          # fake seconds a step takes on the fake timer (10 times real time at h = 1 ms)


def test_wall_clock_hands_over_the_first_state_that_saw_a_new_input_without_waiting_for_the_batch():
    """On the fake timer (_FakeTime: the test is the physics thread), the ROS clock held where five steps are due
    once the input came: the first step that saw it is handed over at once, the batch's end a timer period later."""
    scene = Scene.build(SceneConfig().with_values(**SMALL_MAN))
    ros = {"now": T0}
    loop, log = _loop(scene)
    fake = _FakeTime(loop, scene, [], STEP_COST, ros_now=lambda: ros["now"])
    handed = []
    original = loop.latency.handed_over
    # the time the loop decided each hand-over by (its timer when it took the state), not when the copy was done
    loop.latency.handed_over = lambda used, t: handed.append((used, loop.snapshot.steps, loop._taken[1])) or original(
        used, t)
    loop._follow_clock()                                          # the wall clock starts the scene
    assert scene.sim_time is not None and handed == []
    stamp, names, q, v = next(_samples(0.1))
    loop.take_input(lambda: scene.take_joint_state(T0, names, q, v, received=T0))
    ros["now"] = T0 + 5.5 * scene.h                               # five steps due
    while not (scene.steps_done == 5 and handed and handed[-1][1] == 5):
        assert fake.now() < T0 + 1.0, (scene.steps_done, handed)  # a fake second: the hand-over never came
        loop._follow_clock()
    assert handed[0][0] == 1                                      # nothing before the input placed the body
    assert [h[:2] for h in handed] == [(1, 1), (1, 5)]            # the first step that saw the input, at once;
    assert handed[1][2] - handed[0][2] >= loop.period             # the batch's end a timer period after it
    assert log == [] and loop.latency.percentiles()["latency_state_p50_ms"] > 0


class _FakeTime:
    """The physics thread's world on a fake clock: the test is the thread (SimLoop._follow_clock called in turn),
    a step costs ``step_cost`` fake seconds, the joint states arrive at their stamps (queued as the subscription
    callback would, also during a step), and a wait for an input or the timer moves the clock on to it. The fake
    clock is the loop's timer and its ROS clock, unless ``ros_now`` gives the ROS clock the steps follow. The steps
    of a placement's settle (Scene._settle) cost nothing: its one-off stall is not the hand-over under test."""

    def __init__(self, loop, scene, samples, step_cost, ros_now=None):
        self.t, self.loop, self.scene = T0, loop, scene
        self.pending = deque(samples)
        loop.timer = self.now
        loop.now = ros_now or self.now
        loop._wait = self.wait
        real_step, real_settle, settling = scene.integrator.step, scene._settle, [False]

        def step(*args):
            if not settling[0]:
                self.t += step_cost
                self.deliver()
            return real_step(*args)

        def settle():
            settling[0] = True
            try:
                real_settle()
            finally:
                settling[0] = False
        scene.integrator.step = step
        scene._settle = settle

    def now(self):
        return self.t

    def deliver(self):
        while self.pending and self.pending[0][0] <= self.t:
            stamp, names, q, v = self.pending.popleft()
            self.loop.take_input(lambda s=stamp, q=q, v=v: self.scene.take_joint_state(s, names, q, v, received=s))

    def wait(self, timeout=None):
        if not self.loop._queue:
            wake = self.t + (self.loop.period if timeout is None else min(timeout, self.loop.period))
            self.t = max(self.t, min(wake, self.pending[0][0]) if self.pending else wake)
        self.deliver()


@pytest.mark.parametrize("step_cost", [0.1e-3, 0.6e-3])
def test_a_streamed_body_hands_over_about_one_state_per_input(step_cost):
    """Clock "wall" with joint states at 120 Hz, on a fake clock (steps at 10 and at 1.7 times real time): the
    first state that saw each input is handed over at once, the state a batch ends on only when no hand-over is
    a timer period old: about one snapshot (and one output check) per input, and never a state older than a
    period and a batch (1.7 periods) plus the step in progress."""
    scene = Scene.build(SceneConfig().with_values(**SMALL_MAN))
    loop, log = _loop(scene)
    samples = list(_samples(1.0))
    fake = _FakeTime(loop, scene, samples, step_cost)
    handed = []
    original = loop.latency.handed_over
    loop.latency.handed_over = lambda used, t: handed.append((loop.snapshot.sim_time, fake.now())) or original(used, t)
    while fake.pending or loop._queue or scene.sim_time < samples[-1][0] + 2 * loop.period:
        loop._follow_clock()
    assert log == [] and scene.inputs.accepted == len(samples)
    assert scene.settle_steps > 0 and len(samples) <= len(handed) <= 1.25 * len(samples), len(handed)
    late = max(at - sim_time for sim_time, at in handed[10:])
    print(f"{len(handed)} hand-overs for {len(samples)} inputs; oldest state handed over {late * 1e3:.2f} ms behind")
    assert late <= 1.7 * loop.period + scene.h + step_cost, late
    assert handed[-1][0] >= samples[-1][0]                     # the last input's state was handed over


def test_the_outputs_check_a_snapshot_once_and_never_show_one_that_fails():
    """The physics thread hands a state over as copies, checks it not (its time goes to steps); the output side
    checks each snapshot once (SimLoop.shown): a state torn from its bones is never shown, the last good one
    stays shown, and the refusal is counted once."""
    scene = Scene.build(SceneConfig().with_values(**SMALL_MAN))
    loop, log = _loop(scene)                                      # not started: the test is the physics thread
    samples = _samples(0.1)
    for _ in range(3):
        stamp, names, q, v = next(samples)
        scene.take_joint_state(stamp, names, q, v, received=stamp)
    scene.advance_to(scene.stream.newest)
    loop._take_snapshot(3)
    good = loop.snapshot
    assert loop.stages.totals["checks"] == 0.0 and loop.stages.totals["output_checks"] == 0.0
    assert loop.shown() is good and loop.refused == 0 and loop.stages.totals["output_checks"] > 0
    i = int(scene.surface_vertices[0])
    scene.state.u[i] += np.array([0.0, 0.0, 0.5])                # torn 0.5 m from its bone
    loop._take_snapshot(3)
    torn = loop.snapshot
    assert torn is not good and loop.shown() is good and loop.shown() is good and loop.refused == 1
    assert f"surface vertex {i} is" in torn.problem() and loop.unpublishable == 1
    scene.state.u[i] -= np.array([0.0, 0.0, 0.5])
    loop._take_snapshot(3)
    assert loop.shown() is loop.snapshot and loop.snapshot is not good and loop.refused == 1 and log == []


def test_the_input_queue_is_bounded_and_counts_what_it_drops():
    """A physics thread that cannot keep up (here: not started) holds at most INPUT_QUEUE samples; the callback
    never waits: the samples beyond are dropped, counted and reported, and the queued ones are still taken."""
    scene = Scene.build(SceneConfig().with_values(**SMALL_MAN))
    loop, log = _loop(scene)
    taken = []
    for k in range(INPUT_QUEUE + 3):
        loop.take_input(lambda k=k: taken.append(k))
    assert (loop.waiting, loop.queue_full) == (INPUT_QUEUE, 3)
    warnings = [text for level, text in log if level == "warning"]
    assert len(warnings) == 3 and f"{INPUT_QUEUE} samples wait for physics (3 dropped so far)" in warnings[-1]
    loop.start()
    try:
        _wait_for(lambda: loop.waiting == 0, what="the queue to drain")
    finally:
        assert loop.stop()
    assert taken == list(range(INPUT_QUEUE))              # in order, none lost but the ones counted


def test_the_physics_thread_imports_no_ros():
    import subprocess
    import sys
    code = ("import sys\nimport clusterfem_ros.sim_loop\n"
            "print(','.join(sorted(m for m in sys.modules if m.split('.')[0] == 'rclpy' "
            "or m.split('.')[0].endswith('_msgs'))))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "", f"ROS modules imported by sim_loop: {out.stdout.strip()}"


def test_the_wall_clock_waits_for_late_joint_states_instead_of_jumping_over_them():
    """A node short of CPU receives its joint states in bursts: physics steps up to the newest sample while it
    is at most physics.input_wait behind the clock, so the late ones are interpolated, not jumped over; past the
    wait it steps on, holding the pose."""
    scene = Scene.build(SceneConfig().with_values(**SMALL_MAN, physics__input_wait=0.25))
    wait = scene.config.physics.input_wait
    samples = _samples(0.5)
    for _ in range(3):
        stamp, names, q, v = next(samples)
        scene.take_joint_state(stamp, names, q, v, received=stamp)
    newest = scene.stream.newest
    assert scene.wall_target(newest + 0.5 * wait) == newest                  # late inputs are waited for
    assert scene.wall_target(newest + 2.0 * wait) == pytest.approx(newest + wait)   # then physics goes on
    assert scene.wall_target(newest - 0.01) == newest - 0.01                    # never ahead of the clock
    idle = Scene.build(SceneConfig().with_values(**SMALL_MAN))
    assert idle.config.physics.input_wait == 0.0 and idle.wall_target(123.0) == 123.0   # the default: the clock
