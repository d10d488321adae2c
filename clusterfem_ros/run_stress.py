"""A recorded run's stress on its surface frames, and the one colour scale of its video and picture.

The surface Markers carry colours on the scale the node used live (``output.stress_max``, default E / 20),
which saturates on a long walk; the stress PointClouds carry the values. ``RunStress`` gives each corner of
each surface frame the von Mises stress of its vertex in the stress cloud nearest in time (the corners are
matched to the cloud's vertices once, by position, on the frame closest in time to a cloud) and chooses the
scale from the run itself: the ``percentile`` of the surface vertices' stress over every cloud of the run, so
the colours spread over what this run did and only the top 1 % saturates.
"""
from __future__ import annotations

import numpy as np

PERCENTILE = 99.0
LABEL = "von Mises stress [Pa]"


class RunStress:
    """Per-corner stress of the surface frames of a ``bag_frames.BagFrames`` and the run's scale ``vmax`` [Pa]."""

    def __init__(self, surfaces, stresses, percentile: float = PERCENTILE):
        from scipy.spatial import cKDTree
        if not surfaces or not stresses:
            raise ValueError("a run's stress needs surface Markers and stress clouds: record with "
                             "output.stress_rate_hz > 0")
        # a cloud re-sent before the next physics step carries the same state: one per state
        stresses = [c for k, c in enumerate(stresses) if k == 0 or c.stamp_ns != stresses[k - 1].stamp_ns]
        self.stresses = stresses
        self.cloud_ns = np.array([c.stamp_ns for c in stresses], dtype=np.int64)
        # match corners to cloud vertices on the closest (surface, cloud) pair in time: the same state when a
        # Marker and a cloud were published from one snapshot (distances ~ float32 round-off)
        surface_ns = np.array([s.stamp_ns for s in surfaces], dtype=np.int64)
        k = np.searchsorted(surface_ns, self.cloud_ns).clip(0, len(surfaces) - 1)
        gaps = np.minimum(np.abs(surface_ns[k] - self.cloud_ns),
                          np.abs(surface_ns[np.maximum(k - 1, 0)] - self.cloud_ns))
        c = int(np.argmin(gaps))
        s = int(k[c]) if abs(surface_ns[k[c]] - self.cloud_ns[c]) == gaps[c] else int(max(k[c] - 1, 0))
        n_corners = len(surfaces[s].corners)
        distance, self.corner_vertex = cKDTree(stresses[c].points).query(surfaces[s].corners)
        self.match_distance_m = float(distance.max())
        self.n_corners = n_corners
        vertices = np.unique(self.corner_vertex)
        values = np.concatenate([cloud.von_mises[vertices] for cloud in stresses
                                 if len(cloud.von_mises) == len(stresses[c].von_mises)])
        self.percentile = float(percentile)
        self.vmax = float(max(np.percentile(values, percentile), 1e-9))
        self.peak = float(values.max())

    def corners(self, frame) -> np.ndarray | None:
        """(3t,) the stress [Pa] at each corner of surface frame ``frame`` from the cloud nearest in time; None
        when the frame's triangles are not the matched ones (another body size)."""
        if len(frame.corners) != self.n_corners:
            return None
        c = int(np.argmin(np.abs(self.cloud_ns - frame.stamp_ns)))
        vm = self.stresses[c].von_mises
        if len(vm) <= self.corner_vertex.max():
            return None
        return vm[self.corner_vertex]

    def describe(self) -> str:
        return (f"stress scale 0-{self.vmax:.4g} Pa: the {self.percentile:g}th percentile of the surface's von Mises "
                f"stress over the run's {len(self.stresses)} stress clouds (peak {self.peak:.4g} Pa)")


def run_stress_of(frames) -> RunStress | None:
    """``RunStress`` of a bag's frames, or None when it recorded no stress clouds."""
    if not frames.stresses:
        return None
    return RunStress(frames.surfaces, frames.stresses)
