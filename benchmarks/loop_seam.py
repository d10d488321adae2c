"""Loop seams of real captures: does a looped clip cross its seam smoothly, upright, carrying its heading on?

    python -m benchmarks.loop_seam [FILE.bvh ...] [--seconds 13] [--blend 0.5]

Each clip (the files given, else every clip of tests/data/mocap_clips.yaml found, benchmarks/clips.py) is
loaded as the player loads it (unit, axes and floor found from the skeleton) and looped for ``--seconds`` as
the player loops it (``Motion.looping``: a slerp seam, the root's heading and position carried on), and, for
comparison, through ``JointTrajectory.with_seam`` (every Euler channel blended on its own, only the root's
horizontal position carried), sampled at 120 Hz. Columns:

- unit / height: what the loader decided (its log line) and the skeleton's rest height [m];
- seam step: the largest turn of any joint between two samples within 0.3 s of a seam, over the largest
  anywhere else in the run (1 or less: the seam is no faster than the motion itself);
- tilt: the root's largest tilt from its up axis over the run, and in the clip itself [deg]; a loop that
  lays the body down shows a tilt the clip does not have;
- heading / loop: the root's turn about up from one loop's start to the next's [deg] (the clip's own change
  of heading when carried on; 0 when it snaps back).
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

RATE_HZ = 120.0


def _rotations(tr, motion, q: np.ndarray) -> list[Rotation]:
    """Per BVH joint with three rotation channels, its rotations (file frame) at the samples q (S, n)."""
    out = []
    for j in motion.joints:
        rot = [c for c in j.channels if c.endswith("rotation")]
        if len(rot) == 3:
            cols = [tr.names.index(f"{j.name}_{c[0]}rot") for c in rot]
            out.append(Rotation.from_euler("".join(c[0] for c in rot), q[:, cols]))
    return out


def seam_report(path: Path, seconds: float = 13.0, blend: float = 0.5) -> dict:
    """The columns of the module docstring for the clip at ``path``, for the player's loop and the channel blend."""
    from clusterfem_ros.motion import load_motion
    from clusterfem_ros.skeleton.capture_loop import twist
    m = load_motion("bvh", path)
    capture = m.capture
    up = capture.to_ros[2]
    T = m.trajectory.duration
    blend = min(blend, 0.5 * T)
    times = np.arange(0.0, seconds, 1.0 / RATE_HZ)
    near = np.zeros(times.size - 1, bool)
    for k in range(1, int(seconds / T) + 1):
        near |= np.abs(0.5 * (times[1:] + times[:-1]) - k * T) < 0.3
    row = {"clip": path.stem, "placement": capture.placement, "loops": seconds / T}
    own = np.array([m.trajectory.sample(t)[0] for t in np.arange(0.0, T, 1.0 / RATE_HZ)])
    root_own = _rotations(m.trajectory, capture, own)[0]
    row["tilt_clip"] = float(np.rad2deg(np.arccos(np.clip(root_own.apply(up) @ up, -1, 1))).max())
    for name, tr in (("slerp", m.looping(blend)), ("channels", m.trajectory.with_seam(blend, m.carry))):
        q = np.array([tr.sample(t, loop=True)[0] for t in times])
        rots = _rotations(tr, capture, q)
        steps = np.max([(R[:-1].inv() * R[1:]).magnitude() for R in rots], axis=0)
        row[f"seam_{name}"] = float(steps[near].max() / max(steps[~near].max(), 1e-12)) if near.any() else 0.0
        root = rots[0]
        row[f"tilt_{name}"] = float(np.rad2deg(np.arccos(np.clip(root.apply(up) @ up, -1, 1))).max())
        starts = [tr.sample(k * T + 1e-9, loop=True)[0] for k in range(2)]
        r0, r1 = _rotations(tr, capture, np.array(starts))[0]
        turn = float(np.rad2deg(twist(r1 * r0.inv(), up)[0]))
        row[f"heading_{name}"] = (turn + 180.0) % 360.0 - 180.0
    return row


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("files", nargs="*", type=Path, help="BVH files (default: the manifest's clips found)")
    ap.add_argument("--seconds", type=float, default=13.0, help="looped run length [s] (default 13)")
    ap.add_argument("--blend", type=float, default=0.5, help="the player's loop_blend [s] (default 0.5)")
    a = ap.parse_args(argv)
    files = list(a.files)
    if not files:
        from benchmarks.clips import find_clip, load_manifest
        files = [f for f in (find_clip(c) for c in load_manifest()) if f is not None]
    print("| clip | unit, height | loops | seam step slerp / channels | tilt slerp / channels / clip [deg] | "
          "heading per loop slerp / channels [deg] |")
    print("|---|---|---|---|---|---|")
    for f in files:
        r = seam_report(f, a.seconds, a.blend)
        unit = r["placement"].split("unit ", 1)[1].split(" (", 1)[0]
        height = r["placement"].split("skeleton ", 1)[1].split(" m tall", 1)[0]
        print(f"| {r['clip']} | {unit}, {height} m | {r['loops']:.1f} | {r['seam_slerp']:.2f} / "
              f"{r['seam_channels']:.2f} | {r['tilt_slerp']:.0f} / {r['tilt_channels']:.0f} / {r['tilt_clip']:.0f} | "
              f"{r['heading_slerp']:+.0f} / {r['heading_channels']:+.0f} |", flush=True)


if __name__ == "__main__":
    main()
