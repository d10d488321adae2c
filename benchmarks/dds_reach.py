"""Who sees the node, and what it sends where, per DDS setting: a table.

Each row starts the clusterfem node (the paper's sphere, no skeleton) with one DDS setting and, beside it, a
subscriber to /diagnostics with another, for a few seconds; it counts the diagnostics received and lists the
node's UDP sockets (bound address) and the destinations of every datagram the node sent (strace). Everything runs
in a network namespace made for it (unshare, as root): loopback, and a veth pair with 10.99.0.1/24 and the default
route, standing for the network card, so that traffic meant for other machines has a way out to be counted, and
nothing leaves this machine.

Run: python -m benchmarks.dds_reach [--seconds S]
"""
from __future__ import annotations

import argparse
import collections
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DDS_VARIABLES = ("FASTDDS_BUILTIN_TRANSPORTS", "ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_LOCALHOST_ONLY", "ROS_STATIC_PEERS",
                 "ROS_DISCOVERY_SERVER", "FASTDDS_DEFAULT_PROFILES_FILE", "FASTRTPS_DEFAULT_PROFILES_FILE")
# (node's variables, subscriber's variables, what the row is)
ROWS = [({}, {}, "node started bare (our default), subscriber with ROS defaults"),
        ({}, {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}, "node bare, subscriber in a shell after scripts/env.sh"),
        ({"FASTDDS_BUILTIN_TRANSPORTS": "SHM"}, {}, "node with shared memory only, subscriber with ROS defaults"),
        ({"ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET"}, {}, "node asked for the network (SUBNET), ROS defaults")]
NETWORK = ("ip link set lo up && ip link add cf0 type veth peer name cf1 && ip addr add 10.99.0.1/24 dev cf0 && "
           "ip link set cf0 up && ip link set cf1 up && ip route add default dev cf0")
SUBSCRIBER = r'''
import sys, time, rclpy
from diagnostic_msgs.msg import DiagnosticArray
rclpy.init()
n = rclpy.create_node("reach_probe")
got = []
n.create_subscription(DiagnosticArray, "/diagnostics", got.append, 10, raw=True)
t0 = time.monotonic()
while time.monotonic() - t0 < float(sys.argv[1]):
    rclpy.spin_once(n, timeout_sec=0.1)
print(len(got))
'''


def _udp_sockets(pid: int) -> list[str]:
    """Bound address:port of the process's UDP sockets (from /proc: the namespace's table, by socket inode)."""
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        try:
            target = os.readlink(fd)
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    out = []
    for line in Path(f"/proc/{pid}/net/udp").read_text().splitlines()[1:]:
        f = line.split()
        if f[9] in inodes:
            hex_ip, hex_port = f[1].split(":")
            ip = ".".join(str(int(hex_ip[i:i + 2], 16)) for i in (6, 4, 2, 0))
            out.append(f"{ip}:{int(hex_port, 16)}")
    return out


def _destinations(trace: Path) -> dict[str, int]:
    """Datagrams sent per destination class and address, from strace's sendto/sendmsg lines."""
    counts: collections.Counter = collections.Counter()
    for addr in re.findall(r'sin_addr=inet_addr\("([0-9.]+)"\)', trace.read_text()):
        counts[addr] += 1
    return dict(counts)


def _row(node_env: dict, sub_env: dict, seconds: float, tmp: Path, domain: int) -> dict:
    base = {k: v for k, v in os.environ.items() if k not in DDS_VARIABLES}
    base.update(PYTHONPATH=str(ROOT), ROS_DOMAIN_ID=str(domain))
    trace, log = tmp / f"node_{domain}.strace", tmp / f"node_{domain}.log"
    with open(log, "w") as out:
        node = subprocess.Popen(["strace", "-f", "-qq", "-e", "trace=sendto,sendmsg,sendmmsg", "-o", str(trace),
                                 sys.executable, "-m", "clusterfem_ros.nodes.clusterfem_node", "--ros-args",
                                 "-p", "body.kind:=sphere", "-p", "skeleton.source:=none"],
                                env={**base, **node_env}, stdout=out, stderr=subprocess.STDOUT)
    python: list[int] = []
    try:
        deadline = time.monotonic() + 120
        while "scene ready" not in log.read_text() and node.poll() is None and time.monotonic() < deadline:
            time.sleep(0.2)                            # the node is up once its scene is
        sub = subprocess.run([sys.executable, "-c", SUBSCRIBER, f"{seconds:g}"], env={**base, **sub_env},
                             capture_output=True, text=True, timeout=120 + seconds)
        python = [int(p) for p in subprocess.run(["pgrep", "-P", str(node.pid)], capture_output=True,
                                                  text=True).stdout.split()]
        sockets = sorted(set(_udp_sockets(python[0]))) if python else []
    finally:
        for pid in python:                             # the node itself, then strace ends with it
            os.kill(pid, signal.SIGINT)
        try:
            node.wait(timeout=30)
        except subprocess.TimeoutExpired:
            node.kill()
            node.wait()
    received = int(sub.stdout.strip().splitlines()[-1]) if sub.returncode == 0 else -1
    return {"received": received, "sockets": sockets, "sent_to": _destinations(trace)}


def _inside(seconds: float) -> None:
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for k, (node_env, sub_env, what) in enumerate(ROWS):
            rows.append({"what": what, "node": node_env, "subscriber": sub_env,
                         **_row(node_env, sub_env, seconds, Path(tmp), 90 + k)})
    print(json.dumps(rows))


def _describe(env: dict) -> str:
    return " ".join(f"{k}={v}" for k, v in env.items()) or "(none)"


def _address_class(addr: str) -> str:
    if addr.startswith("127."):
        return "loopback"
    if 224 <= int(addr.split(".")[0]) <= 239:
        return "multicast"
    return "own address" if addr == "10.99.0.1" else "other"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=6.0, help="how long the subscriber listens (default 6)")
    ap.add_argument("--inside", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.inside:
        _inside(args.seconds)
        return 0
    missing = [t for t in ("unshare", "ip", "strace", "pgrep") if shutil.which(t) is None]
    if missing:
        raise SystemExit(f"needs {', '.join(missing)}")
    t0 = time.perf_counter()
    run = subprocess.run(["unshare", "--net", "sh", "-c", NETWORK + ' && exec "$0" "$@"', sys.executable, "-m",
                          "benchmarks.dds_reach", "--inside", "--seconds", f"{args.seconds:g}"], cwd=ROOT,
                         capture_output=True, text=True)
    if run.returncode:
        raise SystemExit(f"the namespace run failed (unshare --net needs root): {run.stderr[-2000:]}")
    rows = json.loads(run.stdout.strip().splitlines()[-1])
    print(f"| node's DDS variables | subscriber's | /diagnostics received in {args.seconds:g} s | node's UDP sockets "
          "bound | node's datagrams sent to |")
    print("|---|---|---|---|---|")
    for r in rows:
        by_class: collections.Counter = collections.Counter()
        for addr, n in r["sent_to"].items():
            by_class[f"{_address_class(addr)} {addr}" if _address_class(addr) != "loopback" else "127.0.0.1"] += n
        sent = ", ".join(f"{k}: {n}" for k, n in sorted(by_class.items())) or "none (no UDP)"
        bound = sorted({s.split(":")[0] for s in r["sockets"]})
        print(f"| {_describe(r['node'])} | {_describe(r['subscriber'])} | {r['received']} | "
              f"{len(r['sockets'])} on {', '.join(bound) or '-'} | {sent} |")
    print(f"\n({time.perf_counter() - t0:.0f} s; rows: " + "; ".join(r["what"] for r in rows) + ")")
    return 0


if __name__ == "__main__":
    sys.exit(main())
