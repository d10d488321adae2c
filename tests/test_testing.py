"""The launch-free test example of docs/architecture.md, run as written, and the harness's own promises."""
import re
from pathlib import Path

import pytest

from clusterfem_ros.nodes.testing import RosWorld

pytestmark = pytest.mark.ros
EXAMPLE_PAGE = Path(__file__).resolve().parents[1] / "docs" / "architecture.md"


def _example() -> str:
    section = EXAMPLE_PAGE.read_text().split("## Launch-free tests of your own", 1)[1]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_the_docs_example_runs_as_written():
    scope: dict = {}
    exec(compile(_example(), "docs/architecture.md example", "exec"), scope)
    tests = [f for name, f in scope.items() if name.startswith("test_")]
    assert len(tests) == 1
    tests[0]()


def test_a_raising_callback_fails_the_wait_at_once_and_worlds_do_not_hear_each_other():
    from std_msgs.msg import String
    with RosWorld() as a, RosWorld() as b:
        assert a.domain_id != b.domain_id and a.context is not b.context
        heard_a, heard_b = a.collect(String, "chatter", raw=False), b.collect(String, "chatter", raw=False)
        pub = a.node("talker").create_publisher(String, "chatter", 10)
        a.wait_for(lambda: pub.get_subscription_count() > 0, 10, "the probe to match")
        pub.publish(String(data="hello"))
        a.wait_for(lambda: len(heard_a) == 1, 10, "the message")
        assert heard_a[0].data == "hello" and heard_b == []

        def boom():
            raise RuntimeError("callback failed")
        a.node("bomb").create_timer(0.01, boom)
        with pytest.raises(AssertionError, match="a node callback raised while waiting for never") as info:
            a.wait_for(lambda: False, 10, "never")
        assert isinstance(info.value.__cause__, RuntimeError)
    with pytest.raises(AssertionError, match="timed out after 0.05 s waiting for nothing"):
        with RosWorld() as c:
            c.node("idle")
            c.wait_for(lambda: False, 0.05, "nothing")
