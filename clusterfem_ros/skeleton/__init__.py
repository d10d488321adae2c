"""The skeleton / motion-source layer (no ROS): URDF kinematics (Pinocchio), joint-state mapping and
interpolation, trajectories from BVH captures, key frames and a built-in walk, the default humanoid and
the jelly body around it. Import the submodules directly, e.g. ``from clusterfem_ros.skeleton.kinematics
import Skeleton``; this package imports nothing heavy on its own."""
