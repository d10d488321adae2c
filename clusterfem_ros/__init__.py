"""clusterfem_ros: skeleton-driven soft bodies with clustered linear FEM (Tang et al. 2009).

Layers, imports one way only (tests/test_layering.py reads every import to check):
  clusterfem_ros.fem, .skeleton, .body, .recording  -- the numerical core: numpy/scipy/numba/pinocchio, no ROS;
                                                       recording is a leaf (CDR bytes in, knows no physics)
  clusterfem_ros.config, .scene, .replay, ...        -- a scene built from its configuration, a bag's replay
  msg_adapters                                       -- numpy arrays <-> ROS messages, no physics
  clusterfem_ros.nodes                               -- rclpy nodes that wire the two
Every error raised on purpose derives from clusterfem_ros.errors.ClusterFemError. Benchmarks are not part of
the package: benchmarks/ in the source tree.
Array conventions: vertices (n, 3) float64 in metres, tets (m, 4) int64 positively oriented,
per-vertex vectors (n, 3) float64.
"""
from .numba_cache import key_the_cache

__version__ = "0.1.0"

# The package's one set-up step: numba's on-disk cache keyed on the sources compiled code can read, before any
# kernel of fem/, skeleton/ or body/ is made (numba fixes a kernel's cache path when it decorates it).
key_the_cache()
