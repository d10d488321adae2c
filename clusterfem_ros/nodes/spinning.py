"""Running a node until the process is asked to stop, the same way for every node's main()."""
from __future__ import annotations

import os
import sys
from pathlib import Path

import rclpy
import yaml
from rclpy.executors import ExternalShutdownException

DEBUG_FLAG, DEBUG_ENV = "--debug", "CLUSTERFEM_DEBUG"
HELP_FLAGS = ("--help", "-h")
PARAMETERS_DOC = "docs/parameters.md"
# Our nodes keep DDS discovery on this machine unless told otherwise, the ROS 2 (Jazzy) way: with
# ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST Fast DDS announces itself to 127.0.0.1 only (no multicast), moves
# data through shared memory, and a ROS tool started with the defaults on the same host (ros2 topic echo,
# RViz, a Foxglove bridge) still finds it: it listens on the unicast ports those announcements reach
# (docs/usage.md "Network" has the measurement). A user's own choice is kept: any of these variables set.
_RANGE_ENV = "ROS_AUTOMATIC_DISCOVERY_RANGE"
_USER_DDS_ENVS = (_RANGE_ENV, "ROS_LOCALHOST_ONLY", "ROS_DISCOVERY_SERVER", "FASTDDS_BUILTIN_TRANSPORTS",
                  "FASTDDS_DEFAULT_PROFILES_FILE", "FASTRTPS_DEFAULT_PROFILES_FILE")
NETWORK_HINT = (f"to reach other machines, start it with {_RANGE_ENV}=SUBNET (or list them in ROS_STATIC_PEERS) "
                "or your own Fast DDS profile")


def spin_until_shutdown(node) -> None:
    """rclpy.spin(node) until Ctrl-C, SIGTERM or an external shutdown.

    SIGINT and SIGTERM shut the context down from rclpy's signal handler; a timer callback already under way
    then fails to publish ("publisher's context is invalid"). That is the shutdown, not an error: only an
    exception raised while the context is still valid propagates.
    """
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        if rclpy.ok(context=node.context):
            raise


def default_discovery(environ=os.environ) -> str | None:
    """Set discovery to this host (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST) unless the user chose a range, a
    transport, a discovery server or a profile; returns the note to log."""
    if any(environ.get(k) for k in _USER_DDS_ENVS):
        return None
    environ[_RANGE_ENV] = "LOCALHOST"
    return (f"DDS: discovery on this host only ({_RANGE_ENV}=LOCALHOST by default; ROS tools on this host see the "
            f"topics with their defaults); {NETWORK_HINT}")


def print_help(prog: str, text: str) -> None:
    """What a node's ``--help`` prints: its usage, its description and where its parameters are documented."""
    print(f"usage: {prog} [--debug] [--ros-args [-p NAME:=VALUE ...] [--params-file FILE] [-r FROM:=TO ...]]\n\n"
          f"{text.strip()}\n\n"
          f"Parameters: every one with its default, range and description in {PARAMETERS_DOC} of the source tree\n"
          f"(or, while the node runs: ros2 param describe /<node> NAME). A params file holds '<node name>:' /\n"
          f"'  ros__parameters:' / '    name: value'; quote text values that YAML reads as booleans ('y', 'on').\n"
          f"--debug (or {DEBUG_ENV}=1) shows the traceback of a start-up error; DDS: {NETWORK_HINT}.")


def run_node(make_node, args=None, help_text: str = "") -> None:
    """A node's main(): rclpy.init, ``make_node()``, spin until shutdown; on every way out (including an
    exception while building the node) the node's ``close()`` if it has one (a recording is finalised),
    then destroy_node and shutdown.

    A node that cannot start (a bad parameter, file or model) prints one line naming the problem and exits
    with status 2; ``--debug`` on the command line (or CLUSTERFEM_DEBUG=1) shows the traceback instead.
    ``--help`` or ``-h`` before ``--ros-args`` prints ``help_text`` with the usage and exits 0.
    """
    argv = list(sys.argv if args is None else args)
    ours = argv[1:argv.index("--ros-args")] if "--ros-args" in argv else argv[1:]
    if any(a in HELP_FLAGS for a in ours):
        print_help(Path(argv[0]).name if argv else "node", help_text)
        raise SystemExit(0)
    debug = DEBUG_FLAG in argv or os.environ.get(DEBUG_ENV, "") not in ("", "0")
    argv = [a for a in argv if a != DEBUG_FLAG]
    note = default_discovery()
    node = None
    try:
        try:
            check_params_files(argv)
            rclpy.init(args=argv)
            node = make_node()
        except Exception as exc:
            if debug:
                raise
            text = " ".join(str(exc).split())          # one line, whatever the exception's layout
            print(f"error: cannot start: {type(exc).__name__}: {text} ({DEBUG_FLAG} or {DEBUG_ENV}=1 shows the "
                  "traceback)", file=sys.stderr)
            raise SystemExit(2) from None
        if note:
            node.get_logger().info(note)
        spin_until_shutdown(node)
    finally:
        if node is not None:
            if hasattr(node, "close"):
                node.close()
            node.destroy_node()
        rclpy.try_shutdown()


def check_params_files(argv: list[str]) -> None:
    """Refuse a ``--params-file`` that rcl would take silently although it sets nothing (a YAML that is a
    string or a list, a node section without a ``ros__parameters`` mapping); ValueError naming the file."""
    for flag, path in zip(argv, argv[1:]):
        if flag != "--params-file":
            continue
        try:
            doc = yaml.safe_load(Path(path).read_text())
        except (OSError, yaml.YAMLError) as exc:
            raise ValueError(f"cannot read params file {path!r}: {exc}") from None
        layout = "write '<node name>:' / '  ros__parameters:' / '    name: value'"
        if not isinstance(doc, dict) or not doc:
            raise ValueError(f"params file {path!r} holds {'nothing' if not doc else 'a ' + type(doc).__name__}, "
                             f"not node sections: {layout}")
        bad = [name for name, sec in doc.items()
               if not (isinstance(sec, dict) and isinstance(sec.get("ros__parameters"), dict))]
        if bad:
            raise ValueError(f"params file {path!r}: sections {bad} have no 'ros__parameters:' mapping: {layout}")
