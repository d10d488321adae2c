"""Where and when a clip's body loses its volume: the frame of the worst |V/V0 - 1|, and the joints it is lost at.

    python -m benchmarks.volume_where --clips NAME ... [--scene FILE] [--set key=value ...] [--top 6]

Plays each clip as ``benchmarks.clip_soak`` does (looped, 120 Hz, on the input clock) and prints, per clip:

- the frames (times) where |V/V0 - 1| of the published state is largest, with the volume error of the *rigid
  target field* at the same pose (every vertex carried by its own bone, ``SkeletonDriver.rigid_state``): when
  the targets themselves lose the volume, the binding pulls the flesh into it;
- at the worst frame, the volume change of the elements grouped by where they are: elements whose four vertices
  are bound to one bone, elements spanning a parent-child pair of bones (the flesh across a joint), others;
- the joints (a bone's start, where its parent bone ends) whose elements (centroid at rest nearest that joint,
  within one child-bone length) lose the most volume, with the joint's bend from rest at that frame.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from clusterfem_ros.fem.mesh.tet_mesh import signed_volumes
from clusterfem_ros.fem.stability import DivergenceError, StabilityError
from .clip_soak import RATE_HZ, T0, _overrides, looped
from .clips import clip_config, find_clip, load_manifest, played_seconds
from .timing import table


def _bend(R: np.ndarray, R0: np.ndarray, parent: np.ndarray, b: int) -> float:
    """The angle [deg] bone b has turned relative to its parent since the bind pose."""
    p = int(parent[b])
    rel = R[p].T @ R[b] if p >= 0 else R[b]
    rel0 = R0[p].T @ R0[b] if p >= 0 else R0[b]
    c = (np.trace(rel0.T @ rel) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def where(path: Path, overrides: dict, scene_file: Path | None, top: int, seconds: float | None) -> None:
    from clusterfem_ros.motion import load_motion
    from clusterfem_ros.scene import Scene
    motion = load_motion("bvh", path)
    tr = looped(motion)
    scene = Scene.build(clip_config(overrides, scene_file, path), urdf_xml=motion.urdf)
    sk, binding, driver = scene.skeleton, scene.binding, scene.driver
    rest = scene.model.rest
    tets = scene.model.mesh.tets
    v0 = signed_volumes(rest, tets)
    length = played_seconds(tr.duration, seconds)
    series = []                                   # (t, volume error, rigid field's volume error)
    worst = (0.0, None, None)                     # (|err|, t, positions)
    for k in range(int(length * RATE_HZ) + 1):
        t = T0 + k / RATE_HZ
        q, v = tr.sample(k / RATE_HZ, loop=True)
        scene.push_joint_state(t, tr.names, q, v)
        try:
            scene.advance_to(t)
        except (DivergenceError, StabilityError):
            scene.reset()
            continue
        if scene.sim_time is None or scene.output_problem() is not None:
            continue
        err = scene.volume_error()
        poses = scene._poses(scene.sim_time)
        rigid = driver.rigid_state(poses)
        series.append((k / RATE_HZ, err, scene.volume_error_of(rest + rigid.u)))
        if abs(err) > worst[0]:
            worst = (abs(err), k / RATE_HZ, (rest + scene.state.u).copy(), poses.rotation.copy(), q.copy())
    s = np.array(series)
    print(f"\n{path.stem}: {len(s)} states shown; worst |V/V0 - 1| {worst[0]:.1%} at t = {worst[1]:.2f} s; "
          f"target field (every vertex on its target): worst {np.abs(s[:, 2]).max():.1%}, correlation with the body's "
          f"{np.corrcoef(s[:, 1], s[:, 2])[0, 1]:.2f}")
    order = np.argsort(-np.abs(s[:, 1]))
    picked = []
    for i in order:                               # the worst frames, at least 0.1 s apart
        if all(abs(s[i, 0] - s[j, 0]) >= 0.1 for j in picked):
            picked.append(i)
        if len(picked) == top:
            break
    print(table(["t [s]", "body V/V0 - 1", "targets (rigid_state) V/V0 - 1"],
                [[f"{s[i, 0]:.2f}", f"{s[i, 1]:+.1%}", f"{s[i, 2]:+.1%}"] for i in picked]))

    _, _, x, R, q = worst
    dv = signed_volumes(x, tets) - v0
    total0 = v0.sum()
    bones = binding.bone[tets]                    # (m, 4)
    parent = sk.bone_parent
    one = (bones == bones[:, :1]).all(axis=1)
    pair = np.zeros(len(tets), bool)
    for e in np.flatnonzero(~one):
        u = np.unique(bones[e])
        pair[e] = u.size == 2 and (parent[u[0]] == u[1] or parent[u[1]] == u[0])
    rows = []
    for name, m in (("one bone", one), ("a parent-child pair (across a joint)", pair), ("other", ~one & ~pair)):
        rows.append([name, int(m.sum()), f"{v0[m].sum() / total0:.1%}", f"{dv[m].sum() / total0:+.2%}",
                     f"{dv[m & (dv < 0)].sum() / total0:+.2%}"])
    print(table(["elements bound to", "elements", "share of V0", "their dV / V0", "their losses / V0"], rows))

    starts, ends = sk.bone_segments(scene.surface_body.bind_q if scene.surface_body is not None else sk.neutral())
    length_b = np.linalg.norm(ends - starts, axis=1)
    joints = np.flatnonzero(parent >= 0)
    centroid = rest[tets].mean(axis=1)
    d = np.linalg.norm(centroid[:, None, :] - starts[None, joints, :], axis=2)
    nearest = np.argmin(d, axis=1)
    near = d[np.arange(len(tets)), nearest] <= np.maximum(length_b[joints[nearest]], 1e-9)
    R0 = binding.rest_rotation
    rows = []
    for j in np.argsort(np.bincount(nearest[near], weights=dv[near], minlength=joints.size))[:top]:
        m = near & (nearest == j)
        b = int(joints[j])
        rows.append([f"{sk.bone_names[int(parent[b])]} -> {sk.bone_names[b]}", int(m.sum()),
                     f"{dv[m].sum() / total0:+.2%}", f"{dv[m].sum() / max(v0[m].sum(), 1e-300):+.1%}",
                     f"{_bend(R, R0, parent, b):.0f}"])
    print(table(["joint (parent -> child bone)", "elements near it", "their dV / body V0", "their dV / their V0",
                 "bend from bind pose [deg]"], rows))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--clips", nargs="+", required=True, help="manifest names to run")
    ap.add_argument("--scene", type=Path, default=None, help="scene file (default: the default scene)")
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="scene parameters to change")
    ap.add_argument("--seconds", type=float, default=None, help="play each clip this long, looped")
    ap.add_argument("--top", type=int, default=6, help="frames and joints listed")
    args = ap.parse_args(argv)
    for clip in load_manifest():
        if clip.name in args.clips:
            path = find_clip(clip)
            if path is None:
                print(f"[volume_where] {clip.name}: not found")
                continue
            where(path, _overrides(args.set), args.scene, args.top, args.seconds)
    return 0


if __name__ == "__main__":
    sys.exit(main())
