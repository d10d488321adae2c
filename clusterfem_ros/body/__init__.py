"""Binding a soft body to a skeleton and driving it (the paper's section 4, eqs. 7-9).

``binding``: nearest bone and nested levels per vertex; ``constraints``: the constraint kinds (bone,
point, line) as attachment targets; ``driver``: ``SkeletonDriver``, bone poses -> ``Control`` per step;
``anchors``: a scene file's anchor points -> point constraints on the vertices near them.
"""
from .binding import Binding, bind_to_skeleton, segment_distance  # noqa: F401
from .constraints import (LevelGains, LineConstraint, PointConstraint, check_poses,  # noqa: F401
                          rigid_point_motion)
from .driver import SkeletonDriver  # noqa: F401
