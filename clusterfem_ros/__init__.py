"""clusterfem_ros: skeleton-driven soft bodies with clustered linear FEM (Tang et al. 2009).

Layers, imports one way only:
  clusterfem_ros.fem, .skeleton, .body, .recording  -- the numerical core: numpy/scipy/numba/pinocchio, no ROS
  msg_adapters                                       -- numpy arrays <-> ROS messages, no physics
  clusterfem_ros.nodes                               -- rclpy nodes that wire the two
Array conventions: vertices (n, 3) float64 in metres, tets (m, 4) int64 positively oriented,
per-vertex vectors (n, 3) float64.
"""
__version__ = "0.1.0"
