"""Running a node until the process is asked to stop, the same way for every node's main()."""
from __future__ import annotations

import os
import sys
from pathlib import Path

import rclpy
import yaml
from rclpy.executors import ExternalShutdownException

DEBUG_FLAG, DEBUG_ENV = "--debug", "CLUSTERFEM_DEBUG"
# Our nodes keep DDS on this machine unless told otherwise: started bare (console script, ros2 run), Fast DDS
# would open UDP on every interface and multicast discovery. A user's own choice (the variable, or a Fast DDS
# XML profile) is kept.
_TRANSPORT_ENV = "FASTDDS_BUILTIN_TRANSPORTS"
_PROFILE_ENVS = ("FASTDDS_DEFAULT_PROFILES_FILE", "FASTRTPS_DEFAULT_PROFILES_FILE")
NETWORK_HINT = (f"to reach other machines, start it with {_TRANSPORT_ENV}=DEFAULT (UDP and shared memory) "
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


def default_transport(environ=os.environ) -> str | None:
    """Set DDS to shared memory only unless the user chose a transport or a profile; returns the note to log."""
    if _TRANSPORT_ENV in environ or any(environ.get(k) for k in _PROFILE_ENVS):
        return None
    environ[_TRANSPORT_ENV] = "SHM"
    return f"DDS: shared memory only, this machine ({_TRANSPORT_ENV}=SHM by default); {NETWORK_HINT}"


def run_node(make_node, args=None) -> None:
    """A node's main(): rclpy.init, ``make_node()``, spin until shutdown; on every way out (including an
    exception while building the node) the node's ``close()`` if it has one (a recording is finalised),
    then destroy_node and shutdown.

    A node that cannot start (a bad parameter, file or model) prints one line naming the problem and exits
    with status 2; ``--debug`` on the command line (or CLUSTERFEM_DEBUG=1) shows the traceback instead.
    """
    argv = list(sys.argv if args is None else args)
    debug = DEBUG_FLAG in argv or os.environ.get(DEBUG_ENV, "") not in ("", "0")
    argv = [a for a in argv if a != DEBUG_FLAG]
    note = default_transport()
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
