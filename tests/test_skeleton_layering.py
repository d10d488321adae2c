"""The skeleton layer is numerical core: importing all of it pulls in neither rclpy nor any *_msgs package."""
import subprocess
import sys

MODULES = ["kinematics", "fk_kernel", "urdf_builder", "joint_map", "joint_stream", "trajectory", "bvh",
           "bvh_to_urdf", "keyframes", "humanoid", "procedural_walk", "jelly_body"]


def test_skeleton_imports_no_ros():
    code = ("import sys\n" + "".join(f"import clusterfem_ros.skeleton.{m}\n" for m in MODULES)
            + "bad = sorted(m for m in sys.modules if m.split('.')[0] == 'rclpy' or m.split('.')[0].endswith('_msgs'))\n"
            + "print(','.join(bad))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "", f"ROS modules imported by the skeleton layer: {out.stdout.strip()}"
