"""Every arm, legged robot and humanoid of example-robot-data under a soft cover, its joints swept: does each get a
body, and does the body hold?

    python -m benchmarks.robot_soak [--seconds 4] [--robots panda solo12 ...] [--families arms legged humanoids]
                                    [--set key=value ...]

Per robot (ROBOTS: the package's URDFs of those three families, one row each) the scene is the robot scenes'
(config/robot_panda.yaml: body.kind robot_cover around the collision shapes, skeleton.root_joint fixed), built on
the robot's URDF, and the joint sweep (skeleton/joint_sweep.py) is played at 120 Hz for ``--seconds``, stepping
up to each sample's stamp as the node does on the input clock. A robot whose URDF Pinocchio or the scene refuses
gets a row with the refusal. Columns:

- links / joints: the URDF's links, and the joints the sweep plays (mimic joints included);
- tets: the cover's tet count; covered: shaped links with a cover / shaped links;
- sub-steps: the most explicit sub-steps a step took; steps/s: physics steps per wall second of stepping
  (measured under whatever load the machine has);
- resets: DivergenceError raised by advance_to (the state failed Scene.state_problem), each followed by a reset;
- worst volume: the largest |V/V0 - 1| over the states checked;
- worst vertex to link: the largest distance of a vertex from where its link carries its rest position [mm]
  (how far the soft cover lags or sags from rigid);
- build: seconds to build the scene (shapes, voxels, model, kernels).

Needs example-robot-data (requirements.lock); without it the command says so and stops.
"""
from __future__ import annotations

import argparse
import sys
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import numpy as np
import yaml

from .timing import table

RATE_HZ = 120.0
T0 = 1000.0
SCENE = "config/robot_panda.yaml"
PREFIX = "package://example-robot-data/robots/"

# family -> (name, URDF under example-robot-data's robots/): every URDF of the package's arms, legged robots and
# humanoids (hands, aerial robots, mobile manipulators and toy pendulums are other families; ur3.urdf is a stub
# without links)
ROBOTS = {
    "arms": [
        ("panda", "panda_description/urdf/panda.urdf"),
        ("panda_collision", "panda_description/urdf/panda_collision.urdf"),
        ("ur3", "ur_description/urdf/ur3_robot.urdf"),
        ("ur3_gripper", "ur_description/urdf/ur3_gripper.urdf"),
        ("ur3_limited", "ur_description/urdf/ur3_joint_limited_robot.urdf"),
        ("ur5", "ur_description/urdf/ur5_robot.urdf"),
        ("ur5_gripper", "ur_description/urdf/ur5_gripper.urdf"),
        ("ur5_limited", "ur_description/urdf/ur5_joint_limited_robot.urdf"),
        ("ur10", "ur_description/urdf/ur10_robot.urdf"),
        ("ur10_limited", "ur_description/urdf/ur10_joint_limited_robot.urdf"),
        ("kinova", "kinova_description/robots/kinova.urdf"),
        ("xarm7", "xarm_description/urdf/xarm7.urdf"),
        ("z1", "z1_description/urdf/z1.urdf"),
        ("so100", "so_arm_description/urdf/so100.urdf"),
        ("so101", "so_arm_description/urdf/so101.urdf"),
        ("baxter", "baxter_description/urdf/baxter.urdf"),
        ("talos_left_arm", "talos_data/robots/talos_left_arm.urdf"),
        ("finger_edu", "finger_edu_description/robots/finger_edu.urdf"),
    ],
    "legged": [
        ("solo8", "solo_description/robots/solo.urdf"),
        ("solo12", "solo_description/robots/solo12.urdf"),
        ("bolt", "bolt_description/robots/bolt.urdf"),
        ("anymal_b", "anymal_b_simple_description/robots/anymal.urdf"),
        ("anymal_b_kinova", "anymal_b_simple_description/robots/anymal-kinova.urdf"),
        ("anymal_c", "anymal_c_simple_description/urdf/anymal.urdf"),
        ("a1", "a1_description/urdf/a1.urdf"),
        ("go1", "go1_description/urdf/go1.urdf"),
        ("go2", "go2_description/urdf/go2.urdf"),
        ("b1", "b1_description/urdf/b1.urdf"),
        ("b1_z1", "b1_description/urdf/b1-z1.urdf"),
        ("laikago", "laikago_description/urdf/laikago.urdf"),
        ("hyq", "hyq_description/robots/hyq_no_sensors.urdf"),
        ("quadruped", "quadruped_description/urdf/quadruped.urdf"),
        ("centauro", "centauro_description/urdf/centauro.urdf"),
    ],
    "humanoids": [
        ("talos", "talos_data/robots/talos_reduced.urdf"),
        ("talos_box", "talos_data/robots/talos_reduced_box.urdf"),
        ("talos_corrected", "talos_data/robots/talos_reduced_corrected.urdf"),
        ("talos_full", "talos_data/robots/talos_full_v2.urdf"),
        ("talos_full_box", "talos_data/robots/talos_full_v2_box.urdf"),
        ("romeo", "romeo_description/urdf/romeo.urdf"),
        ("romeo_small", "romeo_description/urdf/romeo_small.urdf"),
        ("romeo_laas_small", "romeo_description/urdf/romeo_laas_small.urdf"),
        ("icub", "icub_description/robots/icub.urdf"),
        ("icub_reduced", "icub_description/robots/icub_reduced.urdf"),
        ("g1", "g1_description/urdf/g1_29dof_rev_1_0.urdf"),
        ("g1_with_hands", "g1_description/urdf/g1_29dof_with_hand_rev_1_0.urdf"),
        ("simple_humanoid", "simple_humanoid_description/urdf/simple_humanoid.urdf"),
        ("simple_humanoid_classical", "simple_humanoid_description/urdf/simple_humanoid_classical.urdf"),
        ("alex_nub_hands", "alex_description/urdf/alex_nub_hands.urdf"),
        ("alex_psyonic_hands", "alex_description/urdf/alex_psyonic_hands.urdf"),
        ("alex_sake_hands", "alex_description/urdf/alex_sake_hands.urdf"),
        ("alexander", "alexander_description/urdf/alexander_v1.lowerBodyOnly.urdf"),
        ("human", "human_description/robots/human.urdf"),
    ],
}


@dataclass
class RobotResult:
    family: str
    robot: str
    links: int = 0
    joints: int = 0
    tets: int = 0
    covered: str = ""
    substeps: int = 0
    steps_per_s: float = 0.0
    resets: int = 0
    worst_volume: float = 0.0
    worst_link_mm: float = 0.0
    build_s: float = 0.0
    seconds: float = 0.0
    problem: str = ""


def robot_config(urdf: str, overrides: dict | None = None):
    """The robot scenes' config (SCENE's clusterfem section) on the URDF ``urdf`` (a package:// name)."""
    from clusterfem_ros.config import load_scene_file
    config = load_scene_file(SCENE)
    return config.with_values({"skeleton.urdf_file": urdf, **(overrides or {})})


def _link_lag(scene, q: np.ndarray) -> float:
    """The largest distance of a vertex from where its bone carries its rest position at ``q`` [m]."""
    b = scene.binding
    poses = scene.skeleton.forward(q)
    target = np.einsum("nij,nj->ni", poses.rotation[b.bone], b.local) + poses.translation[b.bone]
    return float(np.linalg.norm(scene.model.rest + scene.state.u - target, axis=1).max())


def soak(family: str, name: str, path: str, seconds: float, overrides: dict | None = None) -> RobotResult:
    """One robot: build its covered scene, play its joint sweep for ``seconds`` (module docstring)."""
    from clusterfem_ros.fem.stability import DivergenceError, StabilityError
    from clusterfem_ros.motion import load_motion
    from clusterfem_ros.scene import Scene
    from clusterfem_ros.skeleton.robot_data import package_file
    res = RobotResult(family, name, seconds=seconds)
    urdf = PREFIX + path
    text = package_file(urdf).read_text()
    res.links = len(ET.fromstring(text).findall("link"))
    t0 = time.perf_counter()
    notes: list[str] = []
    try:
        motion = load_motion("joint_sweep", urdf)
        scene = Scene.build(robot_config(urdf, overrides), progress=notes.append)
    except Exception as exc:        # a refusal of any kind is a row of the table
        res.problem = f"refused: {type(exc).__name__}: {exc}".splitlines()[0][:200]
        return res
    res.build_s = time.perf_counter() - t0
    tr = motion.trajectory
    res.joints = len(tr.names)
    res.tets = scene.model.mesh.n_tets
    cover = [n for n in notes if n.startswith("robot cover:")]
    if cover:
        res.covered = cover[0].split(" on ")[1].split(" shaped")[0].replace(" of ", "/")
    column = {n: k for k, n in enumerate(tr.names)}
    index = np.array([column.get(n, -1) for n in scene.skeleton.joint_names])
    wall = 0.0
    steps = 0
    for k in range(int(seconds * RATE_HZ) + 1):
        t = T0 + k / RATE_HZ
        q, v = tr.sample(k / RATE_HZ, loop=True)
        scene.push_joint_state(t, tr.names, q, v)
        s0 = time.perf_counter()
        try:
            rep = scene.advance_to(t)
        except (DivergenceError, StabilityError) as exc:
            res.resets += 1
            res.problem = res.problem or str(exc).splitlines()[0][:200]
            scene.reset()
            continue
        wall += time.perf_counter() - s0
        steps += rep.steps
        res.substeps = max(res.substeps, rep.substeps)
        if scene.sim_time is None or k % 12:
            continue
        res.worst_volume = max(res.worst_volume, abs(scene.volume_error()))
        q_full = np.where(index >= 0, q[np.maximum(index, 0)], 0.0)
        res.worst_link_mm = max(res.worst_link_mm, 1e3 * _link_lag(scene, q_full))
    res.steps_per_s = steps / wall if wall > 0 else 0.0
    return res


def _overrides(pairs: list[str]) -> dict:
    out = {}
    for p in pairs:
        key, _, value = p.partition("=")
        out[key] = yaml.safe_load(value)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=4.0, help="seconds of motion per robot (default 4)")
    ap.add_argument("--robots", nargs="*", default=None, help="names to run (default: every robot of the families)")
    ap.add_argument("--families", nargs="*", default=list(ROBOTS), choices=list(ROBOTS))
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="scene parameters to change")
    args = ap.parse_args(argv)
    from clusterfem_ros.skeleton.robot_data import robot_data_folder
    if robot_data_folder() is None:
        print("[robot_soak] example-robot-data is not installed (requirements.lock pins it): nothing to run")
        return 1
    overrides = _overrides(args.set)
    rows = []
    for family in args.families:
        for name, path in ROBOTS[family]:
            if args.robots and name not in args.robots:
                continue
            t0 = time.perf_counter()
            r = soak(family, name, path, args.seconds, overrides)
            print(f"[robot_soak] {name}: {r.tets} tets, {r.resets} resets, {time.perf_counter() - t0:.0f} s"
                  + (f"; {r.problem}" if r.problem else ""), flush=True)
            rows.append([r.family, r.robot, r.links, r.joints, r.tets or "-", r.covered or "-", r.substeps,
                         f"{r.steps_per_s:.0f}", r.resets if r.tets else "-", f"{r.worst_volume * 100:.1f} %",
                         f"{r.worst_link_mm:.1f}", f"{r.build_s:.1f}", r.problem or ""])
    print(f"\nheadless, {SCENE}'s cover on each robot, joint sweep for {args.seconds:g} s"
          f"{' with ' + ', '.join(args.set) if args.set else ''} (times measured under the machine's current load)")
    print(table(["family", "robot", "links", "joints", "tets", "covered links", "sub-steps", "steps/s", "resets",
                 "worst volume", "worst vertex to link [mm]", "build [s]", "problem"], rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
