"""numpy arrays <-> ROS 2 messages (and their CDR bytes). No physics here.

Modules: colormap (scalar -> RGBA), marker (surface mesh -> Marker TRIANGLE_LIST), pointcloud
(stress field -> PointCloud2), joint_state, diagnostics, time (stamps).
"""
