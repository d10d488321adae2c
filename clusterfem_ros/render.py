"""Pictures of the body for people without RViz: a still PNG of one state, and a recorded bag as a video.

    python -m clusterfem_ros.render BAG [--size 1280x720] [--fps 30] [--max-frames N] [--no-gif]
                                        [--renderer auto|vtk|matplotlib]

writes BAG/run.mp4 (H.264 through imageio-ffmpeg, 30 frames per simulated second) and BAG/run.gif (small,
looping): the surface coloured by von Mises stress on one scale for the whole video, chosen from the run
(``run_stress``: the 99th percentile of the surface's stress over the run's stress clouds), with its colour
bar and unit; the skeleton posed from the bag's joint states; the simulated time; the camera following the
body. Frames are drawn by VTK off screen (``render_vtk``: lit, smooth-shaded, on a floor) when an OpenGL
context can be had, else by matplotlib (Agg) as 2-D polygons that this module projects, sorts back to front
and shades itself; the log says which.
"""
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .config import SceneConfig

PNG_VIEWS = ((10, -90, "side (x-z)"), (10, 0, "front (y-z)"))     # (elevation, azimuth [deg], title): azimuth
                                                                   # -90 looks along +y, 0 along -x
AMBIENT = 0.35              # the share of a triangle's colour kept when it faces away from the light


def facing_shade(vertices: np.ndarray, triangles: np.ndarray, light: np.ndarray) -> np.ndarray:
    """Brightness (t,) in [AMBIENT, 1] of every triangle lit along ``light`` (a direction towards the light):
    ``AMBIENT + (1 - AMBIENT) |n . light|``, the unit normal n taken either way round, so a surface reads as a
    shape rather than a flat silhouette."""
    v = np.asarray(vertices, dtype=float)[np.asarray(triangles)]
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    return AMBIENT + (1.0 - AMBIENT) * np.abs(n @ _unit(np.asarray(light, dtype=float)))


def render_surface_png(path: str | Path, vertices: np.ndarray, triangles: np.ndarray, scalars: np.ndarray,
                       title: str = "", label: str = "von Mises stress [Pa]", vmax: float | None = None,
                       cmap: str = "turbo") -> Path:
    """Write a two-view picture (side, front) of the surface; colours are per-triangle means of ``scalars``
    (the colour bar ends at their 99th percentile unless ``vmax`` is given), shaded by each triangle's facing to
    a light above the viewer; each view's box has the body's own proportions, so a standing figure fills it."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    v = np.asarray(vertices, dtype=float)
    tri = np.asarray(triangles)
    s = np.nan_to_num(np.asarray(scalars, dtype=float)[tri].mean(axis=1))
    vmax = float(vmax if vmax else max(np.percentile(s, 99), 1e-12))
    norm = matplotlib.colors.Normalize(0.0, vmax)
    colours = matplotlib.colormaps[cmap](norm(s))
    fig = plt.figure(figsize=(10, 5.5), dpi=110)
    centre = 0.5 * (v.min(0) + v.max(0))
    extent = np.maximum(np.ptp(v, axis=0), 0.05 * np.ptp(v, axis=0).max()) * 1.05
    for k, (elev, azim, name) in enumerate(PNG_VIEWS):
        ax = fig.add_subplot(1, 2, k + 1, projection="3d")
        a, e = np.radians(azim), np.radians(elev + 30.0)          # towards the viewer, from above
        lit = colours.copy()
        lit[:, :3] *= facing_shade(v, tri, np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)]))[:, None]
        ax.add_collection3d(Poly3DCollection(v[tri], facecolors=lit, edgecolors="none", linewidths=0))
        for i, axis in enumerate("xyz"):
            getattr(ax, f"set_{axis}lim")(centre[i] - 0.5 * extent[i], centre[i] + 0.5 * extent[i])
        ax.set_box_aspect(tuple(extent), zoom=1.15)
        ax.view_init(elev=elev, azim=azim)
        getattr(ax, f"set_{'y' if azim == -90 else 'x'}ticklabels")([])     # the depth axis: ticks only
        ax.set_title(name)
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_zlabel("z [m]")
    sm = matplotlib.cm.ScalarMappable(norm=norm, cmap=cmap)
    fig.colorbar(sm, ax=fig.axes, shrink=0.6, label=label)
    if title:
        fig.suptitle(title)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, bbox_inches="tight")
    plt.close(fig)
    return path


# -- the run as a video --------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Camera:
    """Orthographic view from azimuth / elevation [deg] (azimuth 0 looks along -x, 90 along -y; z is up)."""
    azimuth: float = -60.0
    elevation: float = 12.0

    def axes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(right, up, towards the viewer) unit vectors in world coordinates."""
        az, el = np.radians(self.azimuth), np.radians(self.elevation)
        back = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        right = np.array([-np.sin(az), np.cos(az), 0.0])
        return right, np.cross(back, right), back


RENDERERS = ("auto", "vtk", "matplotlib")


@dataclass
class VideoOptions:
    width: int = 1280               # MP4 frame size [px]; multiples of 16 keep the encoder from resizing
    height: int = 720
    fps: float = 30.0               # video frames per simulated second
    max_frames: int = 0             # 0 = the whole recording
    gif_width: int = 480            # the small GIF for the README (0 = no GIF)
    gif_fps: float = 10.0
    camera: Camera = field(default_factory=Camera)
    renderer: str = "auto"          # one of RENDERERS: auto = VTK when it can draw off screen, else matplotlib
    stress_max: float = 0.0         # top of the colour scale [Pa]; 0 = from the run (run_stress)


def _recorded_scale(scene: SceneConfig) -> tuple[float, str]:
    """(stress mapped to the top colour [Pa], colour map) as the node coloured the recorded Markers."""
    return scene.marker_stress_max, scene.output.colormap


class _SkeletonPoser:
    """Bone segments at each frame's time, from the bag's joint states mapped onto the URDF by name."""

    def __init__(self, urdf: str, samples):
        from .skeleton.joint_map import JointMap
        from .skeleton.kinematics import Skeleton
        self.skeleton = Skeleton.from_urdf_string(urdf)
        self.map = JointMap(self.skeleton.joint_names)
        self.samples = samples
        self.next = 0

    def segments(self, stamp_s: float) -> tuple[np.ndarray, np.ndarray]:
        while self.next < len(self.samples) and self.samples[self.next].stamp <= stamp_s:
            s = self.samples[self.next]
            self.map.update(s.names, s.q, s.v)
            self.next += 1
        return self.skeleton.bone_segments(self.map.q)


def skeleton_poser(frames) -> tuple[_SkeletonPoser | None, str | None]:
    """(the bag's skeleton poser, None) or (None, why the skeleton is not drawn)."""
    if frames.urdf and frames.joint_states:
        try:
            return _SkeletonPoser(frames.urdf, frames.joint_states), None
        except (ValueError, NotImplementedError) as exc:     # UrdfError is a ValueError
            return None, f"the skeleton is not drawn: its URDF cannot be posed ({exc})"
    return None, ("the skeleton is not drawn: the bag has no joint states" if frames.urdf else
                  "the skeleton is not drawn: neither the bag nor its scene_parameters.yaml gives a URDF")


class FrameRenderer:
    """Draws one surface frame: the triangles projected by ``Camera``, sorted back to front and shaded by
    their normal's angle to the light, over a floor grid, with the skeleton on top, the simulated time and
    a von Mises colour bar. One matplotlib figure (Agg) is reused: the still parts (colour bar, labels) are
    drawn once and restored, only the moving artists are drawn per frame, which halves a frame's cost.
    Each call returns an (h, w, 3) uint8 image."""

    def __init__(self, frames, options: VideoOptions, stress=None, vmax: float = 0.0, scale_note: str = ""):
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        from matplotlib.collections import LineCollection, PolyCollection

        self.options, self.frames = options, frames
        self.right, self.up, self.back = options.camera.axes()
        first = frames.surfaces[0].corners
        self.floor_z = float(first[:, 2].min())
        self.centre_z = float(0.5 * (first[:, 2].min() + first[:, 2].max()))
        # one scale for the whole video: the largest body extent seen, with a margin
        extent = max(float(np.ptp(s.corners, axis=0).max()) for s in frames.surfaces[:: max(len(frames.surfaces) // 20, 1)])
        self.half = 0.62 * max(extent, 1e-3)
        self.light = _unit(0.5 * self.back + 0.6 * self.up - 0.3 * self.right)
        self.t0 = min([frames.surfaces[0].stamp_ns * 1e-9] + [s.stamp for s in frames.joint_states[:1]])
        self.skeleton, self.skeleton_note = skeleton_poser(frames)
        self.target = None
        self.stress = stress
        recorded_vmax, cmap = _recorded_scale(frames.scene)
        self.vmax = vmax or recorded_vmax
        self.cmap = matplotlib.colormaps[cmap]

        dpi = 100
        self.fig = plt.figure(figsize=(options.width / dpi, options.height / dpi), dpi=dpi)
        self.ax = self.fig.add_axes((0.0, 0.0, 0.86, 1.0))
        self.ax.set_axis_off()
        self.ax.set_aspect("equal")
        self.ax.set_xlim(-self.half, self.half)
        half_y = self.half * options.height / (0.86 * options.width)     # the axes' own aspect
        self.ax.set_ylim(-half_y, half_y)
        # the moving artists are "animated": left out of the full draw, drawn over a saved background
        self.floor = LineCollection([], colors="0.75", linewidths=0.6, zorder=1, animated=True)
        self.body = PolyCollection([], edgecolors="none", linewidths=0, antialiaseds=False, zorder=2, animated=True)
        self.bones = LineCollection([], colors="black", linewidths=1.6, alpha=0.85, zorder=3, animated=True)
        for artist in (self.floor, self.body, self.bones):
            self.ax.add_collection(artist)
        self.clock = self.ax.text(0.03, 0.96, "", transform=self.ax.transAxes, fontsize=13, va="top",
                                  family="monospace", animated=True)
        cax = self.fig.add_axes((0.88, 0.12, 0.03, 0.76))
        bar = self.fig.colorbar(matplotlib.cm.ScalarMappable(matplotlib.colors.Normalize(0.0, self.vmax), cmap),
                                cax=cax)
        bar.set_label("von Mises stress [Pa]" + (f"\n{scale_note}" if scale_note else ""))
        self.fig.text(0.03, 0.02, f"{frames.folder.name}: {frames.scene.body.kind}, "
                      f"{frames.scene.method}", fontsize=8, color="0.4")
        self._plt = plt
        self.fig.canvas.draw()                  # colour bar, labels: drawn once, then restored per frame
        self.background = self.fig.canvas.copy_from_bbox(self.fig.bbox)

    def _follow(self, corners: np.ndarray) -> np.ndarray:
        """The camera target: the body's horizontal centre, eased so that a limb swing does not shake the view."""
        centre = np.array([*corners[:, :2].mean(axis=0), self.centre_z])
        self.target = centre if self.target is None else self.target + 0.35 * (centre - self.target)
        return self.target

    def _project(self, points: np.ndarray, target: np.ndarray) -> np.ndarray:
        p = points - target
        return np.stack([p @ self.right, p @ self.up], axis=-1)

    def _floor_lines(self, target: np.ndarray, step: float = 0.25) -> np.ndarray:
        n = int(np.ceil(2.0 * self.half / step)) + 1
        gx = (np.floor(target[0] / step) + np.arange(-n, n + 1)) * step
        gy = (np.floor(target[1] / step) + np.arange(-n, n + 1)) * step
        z = self.floor_z
        lines = [[(x, gy[0], z), (x, gy[-1], z)] for x in gx] + [[(gx[0], y, z), (gx[-1], y, z)] for y in gy]
        return self._project(np.asarray(lines), target)

    def draw(self, frame) -> np.ndarray:
        tri = frame.corners.reshape(-1, 3, 3)
        target = self._follow(frame.corners)
        normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
        shade = 0.45 + 0.55 * np.abs(normal @ self.light)
        values = self.stress.corners(frame) if self.stress is not None else None
        if values is not None:
            colour = self.cmap(np.clip(values.reshape(-1, 3).mean(axis=1) / self.vmax, 0.0, 1.0))[:, :3]
        else:
            colour = frame.rgba.reshape(-1, 3, 4)[:, :, :3].mean(axis=1)
        colour = colour * shade[:, None]
        order = np.argsort((tri.mean(axis=1) - target) @ self.back)          # far first
        self.body.set_verts(self._project(tri[order], target))
        self.body.set_facecolors(np.clip(colour[order], 0.0, 1.0))
        self.floor.set_segments(self._floor_lines(target))
        t = frame.stamp_ns * 1e-9
        if self.skeleton is not None:
            a, b = self.skeleton.segments(t)
            self.bones.set_segments(self._project(np.stack([a, b], axis=1), target))
        self.clock.set_text(f"t = {t - self.t0:6.2f} s")
        canvas = self.fig.canvas
        canvas.restore_region(self.background)
        for artist in (self.floor, self.body, self.bones, self.clock):
            self.ax.draw_artist(artist)
        return np.asarray(self.fig.canvas.buffer_rgba())[:, :, :3].copy()

    def close(self) -> None:
        self._plt.close(self.fig)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


MAX_GAP_S = 1.0             # simulated time skipped by the node (physics fell behind): shown as one frame


def video_frames(surfaces, fps: float) -> list[int]:
    """For every video frame at ``fps`` per simulated second, the index of the surface frame shown: the latest
    one recorded at or before its time (a recording slower than ``fps`` repeats frames, a faster one skips).
    A gap of more than MAX_GAP_S between recorded states (time the node dropped) plays as one frame."""
    stamps = np.array([s.stamp_ns for s in surfaces], dtype=np.int64)
    step = int(round(1e9 / fps))
    gaps = np.diff(stamps)
    play = np.concatenate([[0], np.cumsum(np.where(gaps > MAX_GAP_S * 1e9, step, gaps))])
    n = int(np.floor(play[-1] * 1e-9 * fps + 1e-9)) + 1
    times = np.round(np.arange(n) * 1e9 / fps).astype(np.int64)
    return list(np.searchsorted(play, times, side="right") - 1)


def run_scale(frames, options: VideoOptions, progress=print):
    """(RunStress or None, vmax [Pa], colour map, note for the colour bar): the one scale of a video."""
    from .run_stress import run_stress_of
    recorded, cmap = _recorded_scale(frames.scene)
    stress = run_stress_of(frames)
    if stress is None:
        progress(f"[render] the bag has no stress clouds: the recorded colours are drawn, on the node's scale 0-"
                 f"{recorded:.4g} Pa (output.stress_max); record with output.stress_rate_hz > 0 for the run's scale")
        return None, recorded, cmap, "node's scale"
    if options.stress_max > 0:
        return stress, options.stress_max, cmap, "scale given"
    progress(f"[render] {stress.describe()}")
    return stress, stress.vmax, cmap, f"0-{stress.vmax:.0f}: {stress.percentile:g}th pct. of run"


def choose_renderer(name: str, progress=print) -> str:
    """'vtk' or 'matplotlib' for ``name`` in RENDERERS (auto: VTK when it can draw off screen here)."""
    if name not in RENDERERS:
        raise ValueError(f"renderer {name!r}: choose one of {', '.join(RENDERERS)}")
    if name == "matplotlib":
        return name
    from .render_vtk import opengl_available
    ok, said = opengl_available()
    if ok:
        progress(f"[render] VTK draws off screen ({said})")
        return "vtk"
    if name == "vtk":
        raise ValueError(f"renderer 'vtk': VTK cannot draw off screen here ({said}); use --renderer matplotlib")
    progress(f"[render] no OpenGL context for VTK ({said}): drawing with matplotlib instead")
    return "matplotlib"


def render_bag(folder: str | Path, mp4: str | Path | None = None, gif: str | Path | None = None,
               options: VideoOptions | None = None, progress=print) -> tuple[Path, Path | None]:
    """Render a recorded bag to an MP4 (H.264 through imageio-ffmpeg) and a small looping GIF.

    ``options.fps`` video frames per simulated second, each the latest recorded state (surface Marker) at its
    time; the default outputs are ``<bag>/run.mp4`` and ``<bag>/run.gif``. ``progress`` gets a line about
    once a second. Returns (mp4 path, gif path or None).
    """
    return render_bags([folder], mp4, gif, options, progress)


def render_bags(folders: list, mp4: str | Path | None = None, gif: str | Path | None = None,
                options: VideoOptions | None = None, progress=print) -> tuple[Path, Path | None]:
    """``render_bag`` of several bags one after the other in one video (each on its own stress scale, said on its
    colour bar); ``options.max_frames`` counts per bag. The default outputs are in the first bag's folder."""
    import imageio.v2 as imageio
    from PIL import Image

    from .bag_frames import read_bag_frames

    options = options or VideoOptions()
    if options.width < 64 or options.height < 64 or options.width % 2 or options.height % 2:
        raise ValueError(f"video size {options.width}x{options.height}: give even sizes of at least 64 px "
                         "(multiples of 16 avoid resizing by the encoder)")
    if not (1.0 <= options.fps <= 120.0):
        raise ValueError(f"video rate {options.fps!r} frames/s: give 1 to 120")
    if not folders:
        raise ValueError("no bag to render: give at least one bag folder")
    kind = choose_renderer(options.renderer, progress)
    bags = [read_bag_frames(folder) for folder in folders]
    mp4 = Path(mp4) if mp4 else bags[0].folder / "run.mp4"
    gif = None if options.gif_width <= 0 else (Path(gif) if gif else mp4.with_suffix(".gif"))
    gif_every = max(int(round(options.fps / options.gif_fps)), 1)
    mp4.parent.mkdir(parents=True, exist_ok=True)
    plans = []
    for frames in bags:
        # a Marker re-sent before the next physics step carries the same state: one frame per state
        surfaces = [s for k, s in enumerate(frames.surfaces)
                    if k == 0 or s.stamp_ns != frames.surfaces[k - 1].stamp_ns]
        shown = video_frames(surfaces, options.fps)
        plans.append((frames, surfaces, shown[: options.max_frames] if options.max_frames > 0 else shown))
    total = sum(len(shown) for _, _, shown in plans)
    small = []
    done = 0
    t_start = t_said = time.perf_counter()
    with imageio.get_writer(mp4, fps=options.fps, codec="libx264", quality=7, macro_block_size=16,
                            ffmpeg_log_level="error") as writer:
        for frames, surfaces, shown in plans:
            if len(bags) > 1:
                progress(f"[render] {frames.folder}")
            stress, vmax, cmap, note = run_scale(frames, options, progress)
            if kind == "vtk":
                from .render_vtk import VtkFrameRenderer
                poser, skeleton_note = skeleton_poser(frames)
                renderer = VtkFrameRenderer(frames, options, stress, vmax, cmap, note, poser)
            else:
                renderer = FrameRenderer(frames, options, stress, vmax, note)
                skeleton_note = renderer.skeleton_note
            if skeleton_note and frames.scene.skeleton.source != "none":
                progress(f"[render] {skeleton_note}")
            image, drawn = None, -1
            try:
                for index in shown:
                    if index != drawn:
                        image, drawn = renderer.draw(surfaces[index]), index
                    writer.append_data(image)
                    if gif is not None and done % gif_every == 0:
                        h = int(round(options.gif_width * image.shape[0] / image.shape[1]))
                        small.append(np.asarray(Image.fromarray(image).resize((options.gif_width, h), Image.LANCZOS)))
                    done += 1
                    now = time.perf_counter()
                    if now - t_said >= 1.0 or done == total:
                        rate = done / max(now - t_start, 1e-9)
                        progress(f"[render] frame {done}/{total} ({100 * done / total:3.0f} %), "
                                 f"{rate:.1f} frames/s, {(total - done) / rate:.0f} s left")
                        t_said = now
            finally:
                renderer.close()
    if gif is not None:
        imageio.mimsave(gif, small, duration=1000.0 * gif_every / options.fps, loop=0)
    return mp4, gif


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"size {text!r}: give WIDTHxHEIGHT in pixels, e.g. 960x720") from None
    return w, h


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m clusterfem_ros.render",
                                 description="Render a recorded bag to an MP4 and a small GIF: the surface coloured "
                                             "by von Mises stress, the skeleton, the simulated time.")
    ap.add_argument("bag", nargs="+", help="bag folder (the one scripts/run prints after 'recording') or its .mcap "
                    "file; several bags play one after the other")
    ap.add_argument("--mp4", default=None, help="video file (default: <bag>/run.mp4)")
    ap.add_argument("--gif", default=None, help="GIF file (default: the video's name with .gif)")
    ap.add_argument("--no-gif", action="store_true", help="write the MP4 only")
    ap.add_argument("--size", type=_size, default=(1280, 720), help="video size WIDTHxHEIGHT (default 1280x720)")
    ap.add_argument("--fps", type=float, default=30.0, help="video frames per simulated second (default 30)")
    ap.add_argument("--gif-width", type=int, default=480, help="GIF width in pixels (default 480)")
    ap.add_argument("--gif-fps", type=float, default=10.0, help="GIF frame rate (default 10)")
    ap.add_argument("--max-frames", type=int, default=0, help="render only the first N video frames (0 = all)")
    ap.add_argument("--renderer", choices=RENDERERS, default="auto",
                    help="auto (default): VTK off screen when an OpenGL context can be had, else matplotlib")
    ap.add_argument("--stress-max", type=float, default=0.0,
                    help="top of the stress colour scale [Pa] (default 0: the run's 99th percentile)")
    ap.add_argument("--azimuth", type=float, default=Camera.azimuth, help="camera azimuth [deg] (default -60)")
    ap.add_argument("--elevation", type=float, default=Camera.elevation, help="camera elevation [deg] (default 12)")
    args = ap.parse_args(argv)
    from .bag_frames import BagFramesError
    options = VideoOptions(width=args.size[0], height=args.size[1], fps=args.fps, max_frames=args.max_frames,
                           gif_width=0 if args.no_gif else args.gif_width, gif_fps=args.gif_fps,
                           camera=Camera(args.azimuth, args.elevation), renderer=args.renderer,
                           stress_max=args.stress_max)
    try:
        t0 = time.perf_counter()
        mp4, gif = render_bags(args.bag, args.mp4, args.gif, options)
    except (BagFramesError, ValueError, OSError) as exc:
        print(f"[render] cannot render {' '.join(args.bag)}: {exc}", file=sys.stderr)
        return 2
    print(f"[render] {mp4}" + (f" and {gif}" if gif else "") + f" in {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
