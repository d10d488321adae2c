"""Every fetched clip played for its whole length on the default scene: does the body survive real motion?

    python -m benchmarks.clip_soak [--clips NAME ...] [--scene FILE] [--set key=value ...] [--node]

Per clip (tests/data/mocap_clips.yaml; files found by bench/clips.py) the BVH is played at 120 Hz, looped as the
player loops it (its default ``loop_blend``: ``Motion.looping``) for its length or ``MIN_SECONDS``, whichever is
longer (``--seconds S``: exactly S), into a
Scene built on the clip's own skeleton (skeleton.source robot_description; the default scene's jelly body, or
``--scene FILE``'s character surface fitted to the clip's skeleton, as ``scripts/run --scene FILE --bvh CLIP``
plays it; ``--set`` changes parameters, e.g. ``--set warping=false``), stepping up to each sample's stamp as
the node does on the input clock. A clip whose skeleton the scene refuses (a character bound in the pose of a
capture with other joint names) is listed with the refusal. Columns:

- resets: DivergenceError raised by advance_to (the state failed Scene.state_problem), each followed by a reset;
- withheld: ticks whose state Scene.output_problem refused (would not be published);
- worst volume / worst bone distance: over the states that passed (what would be published), the largest
  |V/V0 - 1| and the largest distance of a surface vertex to the segment of its bone [m];
- inverted: over the same states, the share of them with an inverted element (det F < 0: signed volume
  below zero), the most elements inverted at once, and the smallest det F (V / V0 of a linear tet). The
  corotated energy has no smooth rotation through inversion (fem/materials/element_warping.py), so these are the states
  where the warped force is least trustworthy;
- step: mean wall time of a physics step (measured under whatever load the machine has);
- joint speed: the fastest revolute joint in the played trajectory (after the BVH loader's despiking) and
  in the raw file frames [rad/s], for choosing input.max_joint_speed;
- source, unit: who made the clip (the manifest's ``source``) and the unit the BVH loader chose for it
  (``unit_found``: metres per file unit, named when it is a known unit);
- height: of the skeleton at rest (feet to the head's end along its own up, skeleton/bone_roles.py) and of the
  body at rest (its vertices' extent along the scene's Z) [m];
- bare: the major bones (pelvis, spine, head, thighs, shins, feet, upper arms, forearms, hands) with no flesh,
  or 'none'; 'not a human' when the skeleton's roles cannot be told (the flesh is then uniform).

``--node`` also plays each clip through the node (the mocap player and the clusterfem node in one process,
physics on the input clock) and checks every published marker against the skeleton: see ``node_soak``.
"""
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from clusterfem_ros.config import SceneConfig
from clusterfem_ros.fem.stability import DivergenceError, StabilityError
from clusterfem_ros.fem.mesh.tet_mesh import signed_volumes
from .clips import MIN_SECONDS, clip_config, find_clip, load_manifest, missing_message, played_seconds
from .timing import table

RATE_HZ = 120.0
T0 = 1000.0                 # stamps far from zero, as on a ROS clock


def looped(motion):
    """The clip's trajectory looped as the player loops it at its default loop_blend (player_node)."""
    from clusterfem_ros.motion import PLAYER_TABLE
    blend = next(p.default for p in PLAYER_TABLE if p.name == "loop_blend")
    return motion.looping(min(blend, 0.5 * motion.trajectory.duration))


@dataclass
class SoakResult:
    clip: str
    seconds: float
    resets: int = 0
    withheld: int = 0
    shown: int = 0
    worst_volume: float = 0.0
    worst_distance: float = 0.0
    inverted_states: int = 0     # states shown with at least one inverted element
    most_inverted: int = 0       # the most elements inverted at once
    min_det: float = 1.0         # the smallest det F = V / V0 of an element
    step_ms: float = 0.0
    rejected: int = 0
    joint_speed: float = 0.0
    raw_joint_speed: float = 0.0
    first_problem: str = ""
    source: str = ""
    unit: str = ""
    skeleton_height: float = 0.0     # [m], at rest, feet to the head's end
    body_height: float = 0.0         # [m], at rest, along the scene's Z
    bare: str = ""                   # major bones without flesh ('none'), or why they cannot be told
    limbs: dict | None = None        # a surface body bound 'auto': {(side, kind): (mean, max) [m]} of its bind
    unbound: tuple = ()              # a surface body's bones left without flesh


def joint_speeds(path: Path) -> tuple[float, float]:
    """(fastest revolute joint of the played trajectory (despiked, speed-limited), of the raw frames) [rad/s],
    frame to frame."""
    from clusterfem_ros.skeleton.bvh import load_bvh
    from clusterfem_ros.skeleton.bvh_to_urdf import MAX_ROTATION_SPEED, bvh_trajectory
    capture = load_bvh(path)
    out = []
    for despike in (True, False):
        tr = bvh_trajectory(capture, despike=despike, max_rotation_speed=MAX_ROTATION_SPEED if despike else None)
        w = np.abs(np.diff(tr.positions[:, tr.revolute], axis=0)) / np.diff(tr.times)[:, None]
        out.append(float(w.max()))
    return out[0], out[1]


KNOWN_UNITS = {1.0: "m", 0.01: "cm", 0.001: "mm", 0.0254: "inch", 0.056444: "cmu"}
MAJOR_ROLES = ("pelvis", "spine", "head", "thigh", "shin", "foot", "upper_arm", "forearm", "hand")


def unit_found(path: Path) -> tuple[str, float]:
    """(the unit, metres per file unit) that the BVH loader (skeleton/bvh.load_bvh) chose for the clip: the one
    place this benchmark takes the unit from, so it reports whatever rule the loader applies."""
    from clusterfem_ros.skeleton.bvh import load_bvh
    unit_m = float(load_bvh(path).unit_m)
    name = next((n for u, n in KNOWN_UNITS.items() if abs(unit_m / u - 1.0) < 1e-6), "")
    return (f"{name} ({unit_m:g} m)" if name else f"{unit_m:g} m"), unit_m


def flesh_check(scene) -> tuple[float, str]:
    """(the skeleton's height in the pose the body was built in [m], the major bones of ``MAJOR_ROLES`` that no
    rest vertex of the body lies within 1.5 of its capsule radius of ('none'), or 'not a human (...)')."""
    from clusterfem_ros.scene_build import jelly_bind_pose
    from clusterfem_ros.skeleton.bone_roles import NotHumanoid, flesh_radii, label_skeleton
    sk = scene.skeleton
    q = scene.surface_body.bind_q if scene.surface_body is not None else jelly_bind_pose(scene.config, sk)
    q = sk.neutral() if q is None else q
    try:
        roles = label_skeleton(sk, q)
    except NotHumanoid as exc:
        return 0.0, f"not a human ({exc})"
    radii, _ = flesh_radii(roles)
    s, e = sk.bone_segments(q)
    rest = scene.model.rest
    missing = []
    for b, name in enumerate(sk.bone_names):
        role = roles.roles[b]
        if role not in MAJOR_ROLES or roles.lengths[b] <= 0:
            continue
        d = e[b] - s[b]
        t = np.clip((rest - s[b]) @ d / max(d @ d, 1e-300), 0.0, 1.0)
        near = np.linalg.norm(rest - s[b] - t[:, None] * d, axis=1) <= 1.5 * radii.get(name, 0.0)
        if not near.any():
            missing.append(f"{name} ({roles.role_of(name)})")
    return roles.height, ", ".join(missing) if missing else "none"


def inverted_elements(positions: np.ndarray, tets: np.ndarray, rest_volumes: np.ndarray) -> tuple[int, float]:
    """(elements with det F < 0, the smallest det F) at ``positions``: det F of a linear tet is its signed volume
    over its rest volume."""
    det = signed_volumes(positions, tets) / rest_volumes
    return int(np.count_nonzero(det < 0.0)), float(det.min())


def headless_soak(path: Path, overrides: dict | None = None, seconds: float | None = None,
                  scene_file: Path | None = None) -> SoakResult:
    """Play the clip at ``path``, looped, into a Scene (of ``scene_file``, default: the default scene) for
    ``played_seconds`` (its length or MIN_SECONDS, or ``seconds``); see the module docstring."""
    from clusterfem_ros.motion import load_motion
    from clusterfem_ros.scene import Scene
    motion = load_motion("bvh", path)
    tr = looped(motion)
    scene = Scene.build(clip_config(overrides, scene_file, path), urdf_xml=motion.urdf)
    length = played_seconds(tr.duration, seconds)
    res = SoakResult(path.stem, length)
    res.unit = unit_found(path)[0]
    res.skeleton_height, res.bare = flesh_check(scene)
    res.body_height = float(np.ptp(scene.model.rest[:, 2]))
    if scene.surface_body is not None:
        res.limbs, res.unbound = scene.surface_body.limb_distances, scene.surface_body.unbound
    tets = scene.model.mesh.tets
    rest_volumes = scene.model.mesh.volumes()
    res.joint_speed, res.raw_joint_speed = joint_speeds(path)
    for k in range(int(length * RATE_HZ) + 1):
        t = T0 + k / RATE_HZ
        q, v = tr.sample(k / RATE_HZ, loop=True)
        res.rejected += sum(1 for kind, _ in scene.push_joint_state(t, tr.names, q, v) if kind != "unknown_joint")
        try:
            scene.advance_to(t)
        except (DivergenceError, StabilityError) as exc:
            res.resets += 1
            res.first_problem = res.first_problem or str(exc)
            try:
                scene.reset()
            except (DivergenceError, StabilityError) as again:     # the placement itself fails: the clip ends here
                res.first_problem += f"; the reset failed too: {again}"
                break
            continue
        if scene.sim_time is None:
            continue
        if scene.output_problem() is not None:
            res.withheld += 1
            continue
        res.shown += 1
        res.worst_volume = max(res.worst_volume, abs(scene.volume_error()))
        res.worst_distance = max(res.worst_distance, float(scene.bone_distance()[0].max()))
        inverted, min_det = inverted_elements(scene.model.rest + scene.state.u, tets, rest_volumes)
        res.inverted_states += inverted > 0
        res.most_inverted = max(res.most_inverted, inverted)
        res.min_det = min(res.min_det, min_det)
    res.step_ms = scene.step_wall_s / max(scene.steps_done, 1) * 1e3
    return res


def _inverted(r: SoakResult) -> str:
    """The inverted column: share of the states shown that had an inverted element, the most at once, min det F."""
    return f"{100.0 * r.inverted_states / max(r.shown, 1):.0f} % / {r.most_inverted} / {r.min_det:.2f}"


def _overrides(pairs: list[str]) -> dict:
    out = {}
    for p in pairs:
        key, _, value = p.partition("=")
        out[key] = yaml.safe_load(value)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--clips", nargs="*", default=None, help="manifest names to run (default: every clip present)")
    ap.add_argument("--scene", type=Path, default=None, help="scene file (default: the default scene's jelly body)")
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="scene parameters to change")
    ap.add_argument("--seconds", type=float, default=None,
                    help="play each clip this long, looped (default: its length or MIN_SECONDS, the longer)")
    ap.add_argument("--node", action="store_true", help="also play each clip through the node")
    args = ap.parse_args(argv)
    overrides = _overrides(args.set)
    rows, node_rows = [], []
    for clip in load_manifest():
        if args.clips and clip.name not in args.clips:
            continue
        path = find_clip(clip)
        if path is None:
            print(f"[clip_soak] skipped: {missing_message(clip)}", flush=True)
            continue
        t0 = time.perf_counter()
        try:
            r = headless_soak(path, overrides, args.seconds, args.scene)
        except ValueError as exc:            # FitError, UrdfError, ConfigError: the scene refuses this skeleton
            print(f"[clip_soak] {clip.name}: refused at start: {exc}", flush=True)
            rows.append([clip.name, clip.source or "CMU", unit_found(path)[0], "-", "", "-", "refused"] + [""] * 7)
            continue
        except Exception as exc:             # any other failure is a row of the table too, named
            print(f"[clip_soak] {clip.name}: failed: {type(exc).__name__}: {exc}", flush=True)
            rows.append([clip.name, clip.source or "CMU", unit_found(path)[0], "-", "", "-",
                         f"failed ({type(exc).__name__})"] + [""] * 7)
            continue
        print(f"[clip_soak] {clip.name}: {r.resets} resets, {time.perf_counter() - t0:.0f} s"
              + (f"; first: {r.first_problem}" if r.first_problem else ""), flush=True)
        rows.append([r.clip, clip.source or "CMU", r.unit, f"{r.skeleton_height:.2f} / {r.body_height:.2f}", r.bare,
                     f"{r.seconds:.1f}", r.resets, r.withheld, f"{r.worst_volume * 100:.1f} %",
                     f"{r.worst_distance:.3f}", _inverted(r), f"{r.step_ms:.2f}", r.rejected,
                     f"{r.joint_speed:.0f} / {r.raw_joint_speed:.0f}"])
        if args.node:
            from .node_soak import node_soak
            n = node_soak(path, overrides, args.seconds, scene_file=args.scene)
            node_rows.append([n.clip, f"{n.seconds:.1f}", n.resets, n.withheld, n.markers, n.markers_far,
                              f"{n.worst_distance:.3f}", n.rejected, f"{n.dropped_s:.2f}"])
    print(f"\nheadless, {args.scene or 'default scene'} on each clip's skeleton{' with ' + ', '.join(args.set) if args.set else ''} "
          "(step time measured under the machine's current load)")
    print(table(["clip", "source", "unit found", "height skeleton / body [m]", "major bones bare", "s", "resets",
                 "withheld", "worst volume", "worst bone distance [m]",
                 "inverted: states / most at once / min det F", "step [ms]", "inputs rejected",
                 "joint speed played / raw [rad/s]"], rows))
    if node_rows:
        print("\nthrough the node (input clock): every published marker checked against the skeleton")
        print(table(["clip", "s", "resets", "withheld", "markers", "markers over the limit",
                     "worst marker vertex to bones [m]", "inputs rejected", "dropped [s]"], node_rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
