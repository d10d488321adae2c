"""Joint states that come after physics stepped past the newest one, holding its pose (wall clock; a node or a
player short of CPU sends or receives them late and in bursts): the skeleton would jump at once to where the
new samples put it; past ``input.max_late_jump`` the body is re-placed on the new pose instead of having its
flesh yanked (a yank tore the default scene's shins)."""
import pytest

from clusterfem_ros.config import SceneConfig
from clusterfem_ros.fem.stability import DivergenceError
from clusterfem_ros.motion import load_motion
from clusterfem_ros.scene import Scene

RATE = 120.0


def _stalls(scene, stall: float, cycles: int = 3, burst: bool = True) -> int:
    """Cycles of 0.5 s of inputs on time, then none for ``stall`` s while physics keeps the clock, then the
    missing samples at once (``burst``: the receiver was starved) or none of them (the player was starved and
    goes on from the clip's time now); returns the resets (DivergenceError) on the way."""
    m = load_motion()
    names = m.trajectory.names
    resets = 0

    def push(k):
        q, v = m.trajectory.sample(k / RATE, loop=True)
        assert scene.push_joint_state(k / RATE, names, q, v, now=k / RATE) == []   # on the node's clock

    def advance(t):
        nonlocal resets
        try:
            scene.advance_to(t)
        except DivergenceError:
            resets += 1
            scene.reset()

    push(0)
    advance(0.0)
    k = 1
    for _ in range(cycles):
        for _ in range(int(0.5 * RATE)):
            push(k)
            advance(k / RATE)
            k += 1
        stalled_to = (k - 1) / RATE + stall
        advance(stalled_to)                              # physics goes on, holding the newest pose
        while k / RATE <= stalled_to:                    # the burst, or the samples never sent
            if burst:
                push(k)
            k += 1
        for _ in range(100):
            advance(scene.sim_time + 1.000001 * scene.h)
    return resets


# 0.6 s without a sample: the player resumes with its root further on than input.teleport_distance, walked, not a
# teleport (a loaded CI host starved two players in one executor for 0.56 s)
@pytest.mark.parametrize("stall, burst", [(0.03, True), (0.1, True), (0.25, False), (0.6, False)])
def test_late_samples_re_place_the_body_instead_of_tearing_it(stall, burst):
    scene = Scene.build(SceneConfig())
    assert _stalls(scene, stall, burst=burst) == 0
    assert scene.late_jumps >= 1 and scene.placed and scene.output_problem() is None
    assert scene.inputs.total_rejected == 0                  # late samples are used, not rejected


@pytest.mark.parametrize("stall, burst", [(0.1, True), (0.25, False)])
def test_without_the_re_placement_the_same_stalls_tear_the_body(stall, burst):
    """The control: the jump allowed without limit, the flesh is yanked and the step loop resets the body."""
    scene = Scene.build(SceneConfig().with_values(input__max_late_jump=100.0))
    assert _stalls(scene, stall, burst=burst) >= 1
    assert scene.late_jumps == 0


def test_samples_on_time_never_re_place_the_body():
    """Inputs ahead of physics (the usual case, and every replay on the input clock) do not count as late."""
    scene = Scene.build(SceneConfig())
    m = load_motion()
    for k in range(120):
        q, v = m.trajectory.sample(k / RATE, loop=True)
        scene.push_joint_state(k / RATE, m.trajectory.names, q, v)
        scene.advance_to(k / RATE)
    assert scene.late_jumps == 0 and scene.steps_done > 900
