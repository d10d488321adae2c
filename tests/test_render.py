"""The video renderer: the bag decoders against rosbags, the camera, the run's stress scale, and a few frames of
the sample bag written to a playable MP4 and GIF (VTK off screen, and the matplotlib fallback), read back with
imageio, with the body on screen in every frame."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from clusterfem_ros.bag_frames import BagFramesError, decode_stress_cloud, decode_surface_marker, read_bag_frames
from clusterfem_ros.render import Camera, VideoOptions, main, render_bag, video_frames
from clusterfem_ros.render_vtk import opengl_available
from tests.ros_env import child_env

SAMPLE = Path(__file__).resolve().parents[1] / "bags" / "sample_default_scene"


def test_the_surface_decoder_equals_rosbags_deserialisation():
    from mcap.reader import make_reader
    from rosbags.highlevel import AnyReader

    with AnyReader([SAMPLE]) as r:
        conn = [c for c in r.connections if c.topic == "/clusterfem/surface"]
        _, _, raw = next(iter(r.messages(connections=conn)))
        msg = r.deserialize(raw, conn[0].msgtype)
    with open(next(SAMPLE.glob("*.mcap")), "rb") as fh:
        _, _, first = next(iter(make_reader(fh).iter_messages(topics=["/clusterfem/surface"])))
    frame = decode_surface_marker(first.data)
    assert frame.stamp_ns == msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
    assert np.array_equal(frame.corners, [[p.x, p.y, p.z] for p in msg.points])
    assert np.array_equal(frame.rgba, np.array([[c.r, c.g, c.b, c.a] for c in msg.colors], dtype=np.float32))
    assert len(frame.corners) % 3 == 0 and len(frame.corners) > 3000


def test_the_decoders_read_back_what_the_node_s_encoders_write_now():
    """bag_frames reads CDR by hand (the core imports no msg_adapters): a fresh Marker and stress cloud from the
    encoders the node publishes with come back exactly, so an encoder and its decoder cannot drift apart."""
    from msg_adapters.marker import surface_marker_cdr
    from msg_adapters.pointcloud import stress_cloud_cdr
    rng = np.random.default_rng(2)
    vertices = rng.normal(size=(40, 3))
    triangles = rng.integers(0, 40, size=(60, 3))
    rgba = rng.uniform(size=(40, 4)).astype(np.float32)
    frame = decode_surface_marker(surface_marker_cdr(vertices, triangles, rgba, "world", 12_345_678_901, "c", 0))
    assert frame.stamp_ns == 12_345_678_901
    assert np.array_equal(frame.corners, vertices[triangles.reshape(-1)])
    assert np.array_equal(frame.rgba, rgba[triangles.reshape(-1)])
    vm = rng.uniform(0.0, 1e4, size=40)
    cloud = decode_stress_cloud(stress_cloud_cdr(vertices, vm, "world", 7_000_000_001))
    assert cloud.stamp_ns == 7_000_000_001
    assert np.array_equal(cloud.points, vertices.astype(np.float32).astype(np.float64))
    assert np.array_equal(cloud.von_mises, vm.astype(np.float32).astype(np.float64))


def test_the_sample_bag_gives_frames_joint_states_and_the_humanoid():
    frames = read_bag_frames(SAMPLE)
    meta = (SAMPLE / "metadata.yaml").read_text()
    assert len(frames.surfaces) == int(meta.split("name: /clusterfem/surface")[1].split("message_count:")[1].split()[0])
    assert len(frames.joint_states) == int(meta.split("name: /joint_states")[1].split("message_count:")[1].split()[0])
    stamps = [s.stamp_ns for s in frames.surfaces]
    assert stamps == sorted(stamps)
    assert frames.urdf and "<robot" in frames.urdf and frames.scene.skeleton.source == "builtin"


def test_the_camera_axes_are_a_right_handed_orthonormal_frame():
    for az, el in ((-60.0, 12.0), (0.0, 0.0), (135.0, 40.0)):
        right, up, back = Camera(az, el).axes()
        m = np.stack([right, up, back])
        assert np.allclose(m @ m.T, np.eye(3), atol=1e-15)
        assert np.allclose(np.cross(right, up), back, atol=1e-15)
        assert up[2] >= 0.0                       # z stays up on screen
    right, up, back = Camera(0.0, 0.0).axes()
    assert np.allclose(back, [1, 0, 0]) and np.allclose(up, [0, 0, 1])


def test_the_stress_decoder_equals_rosbags_deserialisation():
    from mcap.reader import make_reader
    from rosbags.highlevel import AnyReader

    with AnyReader([SAMPLE]) as r:
        conn = [c for c in r.connections if c.topic == "/clusterfem/stress"]
        _, _, raw = next(iter(r.messages(connections=conn)))
        msg = r.deserialize(raw, conn[0].msgtype)
    with open(next(SAMPLE.glob("*.mcap")), "rb") as fh:
        _, _, first = next(iter(make_reader(fh).iter_messages(topics=["/clusterfem/stress"])))
    cloud = decode_stress_cloud(first.data)
    table = np.frombuffer(bytes(msg.data), dtype=np.float32).reshape(msg.width, -1)
    assert cloud.stamp_ns == msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
    assert np.array_equal(cloud.points, table[:, :3].astype(np.float64))
    assert np.array_equal(cloud.von_mises, table[:, 3].astype(np.float64))
    assert len(cloud.von_mises) > 1000 and "von_mises" in [f.name for f in msg.fields]


def test_the_run_scale_is_the_99th_percentile_of_the_surface_stress_over_the_run():
    from clusterfem_ros.run_stress import RunStress
    frames = read_bag_frames(SAMPLE)
    stress = RunStress(frames.surfaces, frames.stresses)
    # the corners were matched to the cloud's vertices on a state both were published from: float32 round-off
    assert stress.match_distance_m < 1e-5
    surface = np.unique(stress.corner_vertex)
    values = np.concatenate([c.von_mises[surface] for c in frames.stresses])
    assert stress.vmax == pytest.approx(np.percentile(values, 99), rel=1e-12)
    assert (values > stress.vmax).mean() == pytest.approx(0.01, abs=0.002)
    # a corner's stress is its vertex's in the cloud nearest in time
    frame = frames.surfaces[len(frames.surfaces) // 2]
    nearest = min(frames.stresses, key=lambda c: abs(c.stamp_ns - frame.stamp_ns))
    assert np.array_equal(stress.corners(frame), nearest.von_mises[stress.corner_vertex])


def test_video_frames_play_the_recording_at_its_simulated_speed():
    class S:
        def __init__(self, t):
            self.stamp_ns = int(round(t * 1e9))
    ten_hz = [S(0.1 * k) for k in range(11)]                 # 1 s at 10 Hz -> 31 frames at 30 fps, each state 3x
    shown = video_frames(ten_hz, 30.0)
    assert len(shown) == 31 and shown[:7] == [0, 0, 0, 1, 1, 1, 2] and shown[-1] == 10
    sixty_hz = [S(k / 60.0) for k in range(61)]              # 60 Hz -> every other state
    assert video_frames(sixty_hz, 30.0) == list(range(0, 61, 2))
    dropped = [S(0.0), S(0.1), S(0.2), S(12.2), S(12.3)]      # 12 s the node dropped: one frame, not a still
    assert video_frames(dropped, 10.0) == [0, 1, 2, 3, 4]


def _body_on_screen(frame: np.ndarray) -> tuple[float, bool]:
    """(share of the picture that is body, whether the body touches the border): the body is what is strongly
    coloured (the stress colour map; the floor, background, text and bones are greys or pale blue)."""
    rgb = frame.astype(int)
    body = (np.ptp(rgb, axis=2) > 90)
    body[:, int(0.84 * frame.shape[1]):] = False                   # the colour bar
    rows, cols = np.flatnonzero(body.any(axis=1)), np.flatnonzero(body.any(axis=0))
    if not rows.size:
        return 0.0, False
    touches = rows[0] == 0 or cols[0] == 0 or rows[-1] == frame.shape[0] - 1 or cols[-1] == frame.shape[1] - 1
    return float(body.mean()), bool(touches)


@pytest.mark.parametrize("renderer", ["vtk", "matplotlib"])
def test_a_few_frames_of_the_sample_bag_make_a_playable_mp4_and_gif(tmp_path, renderer):
    import imageio.v3 as iio

    if renderer == "vtk" and not opengl_available()[0]:
        pytest.skip(f"VTK cannot draw off screen here: {opengl_available()[1]}")
    lines = []
    mp4, gif = render_bag(SAMPLE, tmp_path / "clip.mp4",
                          options=VideoOptions(width=192, height=144, max_frames=9, gif_width=96, gif_fps=10.0,
                                               renderer=renderer),
                          progress=lines.append)
    video = iio.imread(mp4, index=None)
    assert video.shape == (9, 144, 192, 3)
    assert iio.immeta(mp4)["fps"] == pytest.approx(30.0)
    small = iio.imread(gif, index=None)
    # every third frame (10 of 30 per second); the GIF writer merges repeats of one state (the sample is 10 Hz)
    states = video_frames(read_bag_frames(SAMPLE).surfaces, 30.0)[:9:3]
    assert small.shape[0] == 1 + sum(a != b for a, b in zip(states, states[1:])) and small.shape[1:3] == (72, 96)
    assert lines and lines[-1].startswith("[render] frame 9/9 (100 %)")
    assert any("stress scale 0-" in line and "99th percentile" in line for line in lines), lines
    # the body is drawn in every frame, whole (not cut by the border), and moves between frames
    for k, frame in enumerate(video):
        share, touches = _body_on_screen(frame)
        assert share > 0.01 and not touches, (k, share, touches)
    assert np.abs(video[0].astype(int) - video[-1].astype(int)).mean() > 0.5


def test_the_body_stays_on_screen_through_the_whole_sample_bag(tmp_path):
    """Every frame of the sample bag (the camera follows the walk): the body is on screen, never clipped."""
    import imageio.v3 as iio
    if not opengl_available()[0]:
        pytest.skip(f"VTK cannot draw off screen here: {opengl_available()[1]}")
    mp4, _ = render_bag(SAMPLE, tmp_path / "all.mp4", options=VideoOptions(width=160, height=96, fps=10.0,
                                                                           gif_width=0), progress=lambda _: None)
    video = iio.imread(mp4, index=None)
    assert len(video) == len(video_frames(read_bag_frames(SAMPLE).surfaces, 10.0))
    for k, frame in enumerate(video):
        share, touches = _body_on_screen(frame)
        # a body at low stress is dark blue, which the colour test counts only in part: 0.002 of a 160x96 frame
        # is 30 pixels, none where the body is off screen (share 0)
        assert share > 0.002 and not touches, (k, share, touches)


def test_a_folder_without_a_bag_is_refused_with_the_way_out(tmp_path, capsys):
    with pytest.raises(BagFramesError, match="not a bag folder"):
        read_bag_frames(tmp_path)
    assert main([str(tmp_path)]) == 2
    assert "scripts/run printed" in capsys.readouterr().err
    with pytest.raises(ValueError, match="even sizes"):
        render_bag(SAMPLE, tmp_path / "x.mp4", options=VideoOptions(width=101, height=80))


def test_the_main_job_renders_its_recording(tmp_path):
    """scripts/run records a bag and renders it beside the PNG: run.mp4 and run.gif in the bag folder."""
    import imageio.v3 as iio
    from clusterfem_ros.config import SceneConfig, scene_file_text
    scene = tmp_path / "cube.yaml"                  # the paper's cube, its bottom held, sagging under gravity
    scene.write_text(scene_file_text(SceneConfig().with_values(
        body__kind="cube", skeleton__source="none", body__fix_bottom=True, output__marker_rate_hz=10.0)))
    env = child_env(140)
    run = subprocess.run([sys.executable, "-m", "clusterfem_ros.nodes.demo", "--duration", "2", "--scene", str(scene),
                          "--bags", str(tmp_path / "bags")], env=env, capture_output=True, text=True, timeout=300)
    out = run.stdout + run.stderr
    assert run.returncode == 0, out
    bag = Path(run.stdout.split("\n  recording")[1].split()[0])
    assert (bag / "run.mp4").exists() and (bag / "run.gif").exists(), out
    frames = iio.imread(bag / "run.mp4", index=None)
    surfaces = read_bag_frames(bag).surfaces                            # 30 video frames per simulated second
    assert frames.shape == (len(video_frames(surfaces, 30.0)), 720, 1280, 3) and len(surfaces) >= 10, out
    assert (bag / "final_state.png").exists()
    # the summary tells the timed run's numbers, as its table does
    summary = out.split("real-time factor ")[1].split()[0]
    row = out.split("process CPU\n")[1].split("\n")[0].split()
    assert summary == row[3] and out.split("physics steps   ")[1].split()[0] == row[2], out


def test_the_render_command_on_the_sample_bag(tmp_path, capsys):
    """The README's `python -m clusterfem_ros.render bags/sample_default_scene`, written outside the repository."""
    import imageio.v3 as iio
    out = tmp_path / "sample.mp4"
    assert main([str(SAMPLE), "--mp4", str(out), "--size", "128x96", "--max-frames", "3", "--gif-width", "64"]) == 0
    said = capsys.readouterr().out
    assert f"[render] {out} and {out.with_suffix('.gif')}" in said
    assert iio.imread(out, index=None).shape == (3, 96, 128, 3)
    assert iio.imread(out.with_suffix(".gif"), index=None).shape[1:3] == (48, 64)


def test_the_drawn_skeleton_is_the_urdf_posed_by_the_latest_joint_state():
    from clusterfem_ros.render import FrameRenderer
    from clusterfem_ros.skeleton.humanoid import humanoid_urdf
    from clusterfem_ros.skeleton.kinematics import Skeleton
    frames = read_bag_frames(SAMPLE)
    renderer = FrameRenderer(frames, VideoOptions(width=128, height=96))      # the matplotlib fallback
    try:
        assert renderer.skeleton is not None and renderer.skeleton_note is None
        frame = frames.surfaces[len(frames.surfaces) // 2]
        t = frame.stamp_ns * 1e-9
        starts, ends = renderer.skeleton.segments(t)
        latest = [s for s in frames.joint_states if s.stamp <= t][-1]
        reference = Skeleton.from_urdf_string(humanoid_urdf())
        q = np.zeros(reference.nq)
        q[[reference.joint_index(n) for n in latest.names]] = latest.q
        a, b = reference.bone_segments(q)
        assert np.allclose(starts, a, atol=1e-12) and np.allclose(ends, b, atol=1e-12)
    finally:
        renderer.close()


def test_a_bag_without_a_skeleton_is_drawn_without_one(tmp_path):
    import shutil
    import imageio.v3 as iio
    bag = tmp_path / "bag"
    bag.mkdir()
    for f in (next(SAMPLE.glob("*.mcap")), SAMPLE / "metadata.yaml"):
        shutil.copy(f, bag)
    (bag / "scene_parameters.yaml").write_text((SAMPLE / "scene_parameters.yaml").read_text().replace(
        "source: builtin", "source: urdf_file").replace("urdf_file: ''", "urdf_file: missing.urdf"))
    lines = []
    mp4, _ = render_bag(bag, tmp_path / "x.mp4", options=VideoOptions(width=128, height=96, max_frames=2, gif_width=0),
                        progress=lines.append)
    assert any("skeleton is not drawn" in line and "URDF" in line for line in lines), lines
    assert iio.imread(mp4, index=None).shape == (2, 96, 128, 3)


def test_a_triangle_is_brightest_facing_the_light_either_way_round_and_ambient_edge_on():
    from clusterfem_ros.render import AMBIENT, facing_shade
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])           # normal +z
    tris = np.array([[0, 1, 2], [0, 2, 1]])                       # and the same triangle turned over
    assert facing_shade(v, tris, np.array([0.0, 0, 2])) == pytest.approx([1.0, 1.0], abs=1e-15)
    assert facing_shade(v, tris, np.array([1.0, 0, 0])) == pytest.approx([AMBIENT, AMBIENT], abs=1e-15)
    lit = facing_shade(v, tris[:1], np.array([1.0, 0, 1]))[0]     # 45 deg: cos = 1/sqrt(2)
    assert lit == pytest.approx(AMBIENT + (1 - AMBIENT) / np.sqrt(2), rel=1e-14)


def test_the_main_job_s_picture_is_on_its_video_s_stress_scale():
    """final_state.png and run.mp4 of one recording share one scale: the run's (render.run_scale), named with its
    unit on the picture's colour bar; without a recording the picture says it uses its own state's scale."""
    from clusterfem_ros.nodes.demo import _png_scale
    from clusterfem_ros.render import VideoOptions, run_scale
    vmax, label = _png_scale(SAMPLE)
    _, video_vmax, _, _ = run_scale(read_bag_frames(SAMPLE), VideoOptions(), progress=lambda _: None)
    assert vmax == video_vmax and vmax > 0
    assert "[Pa]" in label and "of the run" in label
    assert _png_scale(None) == (None, "von Mises stress [Pa], 0 to the 99th percentile of this state")
