"""Video frames of a recorded bag drawn with VTK (through pyvista), off screen: lit, smooth-shaded, on a floor.

``VtkFrameRenderer.draw(frame)`` returns one (h, w, 3) uint8 image: the surface as a triangle mesh with
per-vertex normals (smooth shading under three lights) coloured by von Mises stress on the run's one scale
(``run_stress``; the recorded Marker colours when the bag has no stress clouds), half see-through so that the
skeleton (dark tubes, posed from the bag's joint states) shows inside it; a checker floor at the lowest point
of the first frame; the stress colour bar with its unit; the simulated time; a perspective camera that
follows the body's horizontal centre, eased.

``opengl_available()`` asks a child process to draw one small picture first: a VTK without an OpenGL
context can abort the process instead of raising, and render.py then falls back to matplotlib.
"""
from __future__ import annotations

import os
import subprocess
import sys

import numpy as np

BODY_OPACITY = 0.72         # the skeleton shows through the flesh
FLOOR_TILE = 0.5            # [m]
FLOOR_TILES = 40            # per side
VIEW_ANGLE = 30.0           # vertical field of view [deg]
FILL = 0.72                 # share of the picture's height the body's largest extent fills

_PROBE = """
import pyvista as pv
p = pv.Plotter(off_screen=True, window_size=(64, 48))
p.add_mesh(pv.Sphere())
img = p.screenshot(return_img=True)
assert img.shape[:2] == (48, 64) and img.std() > 0, img.shape
print(p.ren_win.GetClassName())
p.close()
"""
_available: tuple[bool, str] | None = None


def opengl_available(timeout_s: float = 60.0) -> tuple[bool, str]:
    """(whether VTK can draw off screen here, what it said): a child process draws a sphere (cached)."""
    global _available
    if _available is None:
        # without a display, VTK would try X first and print a warning: ask for EGL (headless GPU or Mesa) first
        tries = [{"VTK_DEFAULT_OPENGL_WINDOW": "vtkEGLRenderWindow"}, {}] if not os.environ.get("DISPLAY") else [{}]
        for extra in tries:
            try:
                out = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True,
                                     timeout=timeout_s, env={**os.environ, **extra})
                said = out.stdout.strip() or (out.stderr.strip().splitlines() or [f"exit code {out.returncode}"])[-1]
                _available = (out.returncode == 0, said)
            except (OSError, subprocess.TimeoutExpired) as exc:
                _available = (False, str(exc))
            if _available[0]:
                os.environ.update(extra)
                break
    return _available


def vertex_normals(points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(n, 3) unit area-weighted vertex normals of a triangle mesh (faces (t, 3))."""
    p = points[faces]
    fn = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    n = np.zeros_like(points)
    for k in range(3):
        np.add.at(n, faces[:, k], fn)
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


class VtkFrameRenderer:
    """Draws the surface frames of one bag (see the module docstring); ``stress`` is a ``run_stress.RunStress``
    or None (then the recorded colours are drawn, on the recorded ``vmax``)."""

    def __init__(self, frames, options, stress, vmax: float, cmap: str, scale_note: str, skeleton):
        import pyvista as pv

        self.options, self.frames, self.stress, self.skeleton = options, frames, stress, skeleton
        first = frames.surfaces[0].corners
        # the Marker repeats a vertex's position at every corner that uses it: the corners' unique positions on
        # the first frame are the vertices, and every later frame has the same triangles
        _, first_index, self.corner_vertex = np.unique(first, axis=0, return_index=True, return_inverse=True)
        self.corner_vertex = self.corner_vertex.reshape(-1)
        self.n_vertices = len(first_index)
        self.faces = self.corner_vertex.reshape(-1, 3)
        self.floor_z = float(first[:, 2].min())
        self.centre_z = float(0.5 * (first[:, 2].min() + first[:, 2].max()))
        step = max(len(frames.surfaces) // 20, 1)
        extent = max(float(np.ptp(s.corners, axis=0).max()) for s in frames.surfaces[::step])
        self.distance = FILL ** -1 * 0.5 * max(extent, 1e-3) / np.tan(np.radians(VIEW_ANGLE / 2))
        self.back = _back(options.camera.azimuth, options.camera.elevation)
        self.t0 = min([frames.surfaces[0].stamp_ns * 1e-9] + [s.stamp for s in frames.joint_states[:1]])
        self.target = None
        self.vmax, self.cmap = vmax, cmap

        pv.OFF_SCREEN = True
        self.plotter = pv.Plotter(off_screen=True, window_size=(options.width, options.height),
                                  lighting="three lights")
        self.plotter.set_background("#f4f6f9", top="#c9d6e8")
        self.mesh = pv.PolyData(self._points(first), np.hstack([np.full((len(self.faces), 1), 3), self.faces]))
        self.mesh.point_data["Normals"] = vertex_normals(self.mesh.points, self.faces)
        self.mesh.point_data.active_normals_name = "Normals"
        bar = dict(title=f"von Mises stress [Pa]\n{scale_note}", vertical=True, position_x=0.87, position_y=0.15,
                   height=0.7, width=0.05, title_font_size=14, label_font_size=13, fmt="%.0f", n_labels=6,
                   color="black")
        if stress is not None:
            self.mesh.point_data["von_mises"] = np.zeros(self.n_vertices)
            self.body = self.plotter.add_mesh(self.mesh, scalars="von_mises", cmap=cmap, clim=(0.0, vmax),
                                              smooth_shading=False, opacity=BODY_OPACITY, specular=0.35,
                                              specular_power=20, scalar_bar_args=bar)
        else:
            self.mesh.point_data["rgb"] = np.zeros((self.n_vertices, 3), dtype=np.uint8)
            self.body = self.plotter.add_mesh(self.mesh, scalars="rgb", rgb=True, opacity=BODY_OPACITY,
                                              specular=0.35, specular_power=20)
            self.plotter.add_scalar_bar(mapper=self._bar_mapper(pv, vmax, cmap), **bar)
        self.body.prop.interpolation = "phong"
        self.floor = pv.Plane(center=(0, 0, self.floor_z), i_size=FLOOR_TILE * FLOOR_TILES,
                              j_size=FLOOR_TILE * FLOOR_TILES, i_resolution=FLOOR_TILES, j_resolution=FLOOR_TILES)
        ij = np.indices((FLOOR_TILES, FLOOR_TILES)).reshape(2, -1).sum(axis=0) % 2
        self.floor.cell_data["tile"] = np.where(ij[:, None] == 1, [168, 174, 184], [214, 218, 224]).astype(np.uint8)
        self.floor_points = self.floor.points.copy()
        self.plotter.add_mesh(self.floor, scalars="tile", rgb=True, lighting=False)
        self.bones = None
        if skeleton is not None:
            a, b = skeleton.segments(frames.surfaces[0].stamp_ns * 1e-9)
            self.bone_lines = _lines(pv, a, b)
            self.bones = self.plotter.add_mesh(self.bone_lines, color="#202020", line_width=5,
                                               render_lines_as_tubes=True)
        self.clock = self.plotter.add_text("", position="upper_left", font_size=14, color="black", font="courier")
        name = f"{frames.folder.name}: {frames.scene.body.kind}, {frames.scene.method}"
        self.plotter.add_text(name, position="lower_left", font_size=8, color="#555555")
        self.plotter.camera.view_angle = VIEW_ANGLE

    @staticmethod
    def _bar_mapper(pv, vmax: float, cmap: str):
        dummy = pv.PolyData(np.zeros((2, 3)))
        dummy["s"] = [0.0, vmax]
        plotter = pv.Plotter(off_screen=True)
        actor = plotter.add_mesh(dummy, scalars="s", cmap=cmap, clim=(0.0, vmax), show_scalar_bar=False)
        mapper = actor.mapper
        plotter.close()
        return mapper

    def _points(self, corners: np.ndarray) -> np.ndarray:
        out = np.empty((self.n_vertices, 3))
        out[self.corner_vertex] = corners
        return out

    def _follow(self, points: np.ndarray) -> np.ndarray:
        centre = np.array([*points[:, :2].mean(axis=0), self.centre_z])
        self.target = centre if self.target is None else self.target + 0.35 * (centre - self.target)
        return self.target

    def draw(self, frame) -> np.ndarray:
        points = self._points(frame.corners)
        self.mesh.points[:] = points
        self.mesh.point_data["Normals"][:] = vertex_normals(points, self.faces)
        values = self.stress.corners(frame) if self.stress is not None else None
        if self.stress is not None:
            v = np.zeros(self.n_vertices)
            if values is not None:
                v[self.corner_vertex] = values
            self.mesh.point_data["von_mises"][:] = v
        else:
            rgb = np.zeros((self.n_vertices, 3), dtype=np.uint8)
            rgb[self.corner_vertex] = np.clip(frame.rgba[:, :3] * 255.0, 0, 255).astype(np.uint8)
            self.mesh.point_data["rgb"][:] = rgb
        self.mesh.Modified()
        target = self._follow(points)
        snap = np.floor(target[:2] / (2 * FLOOR_TILE)) * 2 * FLOOR_TILE       # the checker stays in place
        self.floor.points[:] = self.floor_points + np.array([snap[0], snap[1], 0.0])
        self.floor.Modified()
        t = frame.stamp_ns * 1e-9
        if self.bones is not None:
            a, b = self.skeleton.segments(t)
            self.bone_lines.points[:] = np.stack([a, b], axis=1).reshape(-1, 3)
            self.bone_lines.Modified()
        self.clock.SetText(2, f"t = {t - self.t0:5.2f} s")
        camera = self.plotter.camera
        camera.focal_point = tuple(target)
        camera.position = tuple(target + self.distance * self.back)
        camera.up = (0.0, 0.0, 1.0)
        camera.clipping_range = (0.05 * self.distance, 4.0 * self.distance + FLOOR_TILE * FLOOR_TILES)
        self.plotter.render()
        return np.asarray(self.plotter.screenshot(return_img=True))[:, :, :3].copy()

    def close(self) -> None:
        self.plotter.close()


def _back(azimuth: float, elevation: float) -> np.ndarray:
    az, el = np.radians(azimuth), np.radians(elevation)
    return np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])


def _lines(pv, a: np.ndarray, b: np.ndarray):
    n = len(a)
    cells = np.hstack([np.full((n, 1), 2), np.arange(2 * n).reshape(n, 2)])
    return pv.PolyData(np.stack([a, b], axis=1).reshape(-1, 3), lines=cells)
