"""A PNG of a deformed surface coloured by a scalar field, for people without RViz (matplotlib, Agg)."""
from __future__ import annotations

from pathlib import Path

import numpy as np


def render_surface_png(path: str | Path, vertices: np.ndarray, triangles: np.ndarray, scalars: np.ndarray,
                       title: str = "", label: str = "von Mises stress [Pa]", vmax: float | None = None,
                       cmap: str = "turbo") -> Path:
    """Write a two-view picture (front, side) of the surface; colours are per-triangle means of ``scalars``."""
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
    fig = plt.figure(figsize=(10, 6), dpi=110)
    centre = 0.5 * (v.min(0) + v.max(0))
    half = 0.5 * np.ptp(v, axis=0).max()
    for k, (elev, azim, name) in enumerate(((10, -90, "side (x-z)"), (10, 0, "front (y-z)"))):
        ax = fig.add_subplot(1, 2, k + 1, projection="3d")
        ax.add_collection3d(Poly3DCollection(v[tri], facecolors=colours, edgecolors="none", linewidths=0))
        for i, axis in enumerate("xyz"):
            getattr(ax, f"set_{axis}lim")(centre[i] - half, centre[i] + half)
        ax.set_box_aspect((1, 1, 1))
        ax.view_init(elev=elev, azim=azim)
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
