"""The package leaves no process-wide state changed behind it: what a body needs while it runs comes back when it
stops, and what a model needs is kept with the model, not in module tables."""
from __future__ import annotations

import sys

import numpy as np
import pytest

from clusterfem_ros.config import SceneConfig
from clusterfem_ros.fem.materials import stress
from clusterfem_ros.scene import Scene
from clusterfem_ros.sim_loop import GIL_SWITCH_INTERVAL, SimLoop


def _loop(scene):
    return SimLoop(scene, lambda: 0.0, 100.0, 250, lambda level, text: None)


def test_two_physics_threads_shorten_the_switch_interval_and_give_it_back():
    before = sys.getswitchinterval()
    sys.setswitchinterval(4e-3)                    # a process's own choice, above the loops' interval
    scene = Scene.build(SceneConfig().with_values(**{"skeleton.source": "none", "body.kind": "cube",
                                                     "body.target_tets": 200}))
    a, b = _loop(scene), _loop(scene)
    try:
        a.start()
        assert sys.getswitchinterval() == pytest.approx(4e-3)      # one body keeps the process's interval
        b.start()
        assert sys.getswitchinterval() == pytest.approx(GIL_SWITCH_INTERVAL)
        assert a.stop() and sys.getswitchinterval() == pytest.approx(4e-3)
        a.stop()                                   # a second stop counts nothing
        assert b.stop() and sys.getswitchinterval() == pytest.approx(4e-3)
    finally:
        a.stop()
        b.stop()
        sys.setswitchinterval(before)


def test_the_stress_keeps_its_rest_data_with_the_model_not_in_a_module_table():
    scene = Scene.build(SceneConfig().with_values(**{"skeleton.source": "none", "body.kind": "cube",
                                                     "body.target_tets": 200}))
    model = scene.model

    def tables():                                   # the sizes of the module's dicts and lists
        return {k: len(v) for k, v in vars(stress).items() if isinstance(v, (dict, list)) and not k.startswith("__")}
    before = tables()
    u = np.random.default_rng(3).normal(scale=1e-3, size=(model.n_vertices, 3))
    first = stress.compute_stress(model, u, corotated=True)
    assert "rest_gradients" in vars(model)          # made once, kept by the model
    assert tables() == before
    again = stress.compute_stress(model, u, corotated=True)
    assert np.array_equal(first.vertex_von_mises, again.vertex_von_mises) and first.vertex_von_mises.max() > 0


@pytest.mark.ros
def test_a_ros_world_sets_its_dds_transport_while_it_lives_and_gives_the_variable_back(monkeypatch):
    """Importing the test harness changes nothing; a RosWorld keeps DDS on shared memory while it lives (unless
    the variable is set), and the variable is as it was once the last world closes."""
    import os
    monkeypatch.delenv("FASTDDS_BUILTIN_TRANSPORTS", raising=False)
    from clusterfem_ros.nodes.testing import RosWorld
    assert "FASTDDS_BUILTIN_TRANSPORTS" not in os.environ
    with RosWorld():
        assert os.environ["FASTDDS_BUILTIN_TRANSPORTS"] == "SHM"
        with RosWorld():
            pass
        assert os.environ["FASTDDS_BUILTIN_TRANSPORTS"] == "SHM"        # the outer world still lives
    assert "FASTDDS_BUILTIN_TRANSPORTS" not in os.environ
    monkeypatch.setenv("FASTDDS_BUILTIN_TRANSPORTS", "UDPv4")
    world = RosWorld()
    assert os.environ["FASTDDS_BUILTIN_TRANSPORTS"] == "UDPv4"            # the user's own choice stands
    world.close()
    world.close()                                                         # a second close counts nothing
    assert os.environ["FASTDDS_BUILTIN_TRANSPORTS"] == "UDPv4"
