"""Named colour maps as 256-entry RGBA look-up tables and scalar -> colour mapping.

The tables are sampled from matplotlib once, on first use (matplotlib is a declared dependency;
pyplot is not imported, so no GUI backend is touched).
"""
from __future__ import annotations

from functools import cache

import numpy as np

COLORMAP_NAMES: tuple[str, ...] = ("viridis", "turbo", "coolwarm", "plasma", "inferno", "magma", "jet")
LUT_SIZE = 256
NONFINITE_RGBA: tuple[float, float, float, float] = (1.0, 0.0, 1.0, 1.0)
"""Colour given to NaN/inf values: opaque magenta, which none of the maps above contains."""


@cache
def colormap_lut(name: str) -> np.ndarray:
    """(256, 4) float32 RGBA table of the named map, values in [0, 1]. Read-only."""
    if name not in COLORMAP_NAMES:
        raise ValueError(f"unknown colour map {name!r}: choose one of {', '.join(COLORMAP_NAMES)}")
    import matplotlib  # local: only the first call pays for the import

    lut = np.asarray(matplotlib.colormaps[name](np.linspace(0.0, 1.0, LUT_SIZE)), dtype=np.float32)
    lut.setflags(write=False)
    return lut


def map_scalars(values: np.ndarray, name: str, vmin: float, vmax: float) -> np.ndarray:
    """Scalars (n,) -> (n, 4) float32 RGBA in [0, 1] through the named map.

    Values are clipped to [vmin, vmax]; vmin == vmax (a uniform field, e.g. zero stress at rest)
    maps every value to the first colour; non-finite values get `NONFINITE_RGBA`, never NaN.
    """
    lut = colormap_lut(name)
    if not (np.isfinite(vmin) and np.isfinite(vmax)):
        raise ValueError(f"colour range [{vmin}, {vmax}] must be finite")
    if vmax < vmin:
        raise ValueError(f"colour range [{vmin}, {vmax}] is reversed: pass vmin <= vmax")
    v = np.asarray(values, dtype=np.float64)
    if v.ndim != 1:
        raise ValueError(f"values must be 1-D (n,), got shape {v.shape}")
    finite = np.isfinite(v)
    span = vmax - vmin
    if span > 0.0:
        t = (np.where(finite, v, vmin) - vmin) * (LUT_SIZE / span)
        index = np.clip(t, 0, LUT_SIZE - 1).astype(np.intp)
    else:
        index = np.zeros(v.shape, dtype=np.intp)
    rgba = lut[index]
    if not finite.all():
        rgba[~finite] = NONFINITE_RGBA
    return rgba
