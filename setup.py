"""clusterfem_ros: installable with `pip install .` and inside a colcon workspace (ament_python)."""
from glob import glob

from setuptools import find_packages, setup

package_name = "clusterfem_ros"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(include=["clusterfem_ros", "clusterfem_ros.*", "msg_adapters", "msg_adapters.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob("config/*")),
    ],
    # runtime data read through the package's own path (so a wheel works from any directory): the measured
    # points of the error budget and the example key frames; benchmarks/ stays in the source tree
    package_data={"clusterfem_ros": ["data/*.csv"], "clusterfem_ros.skeleton": ["data/*.yaml"]},
    # Only what pip should really fetch: rclpy and the message packages come from the ROS install
    # (wheels or apt), and listing them here would pull a second copy.
    # (tests/test_package_manifest.py checks package.xml declares each, and each third-party import is here)
    install_requires=["numpy", "scipy", "numba", "pin", "mcap", "meshio", "pyyaml", "matplotlib", "pillow",
                      "imageio", "imageio-ffmpeg", "trimesh", "pycollada", "rtree", "pytetwild", "pyvista",
                      "fast_simplification", "rosbags", "foxglove-sdk", "platformdirs"],
    zip_safe=True,
    maintainer="clusterfem_ros maintainers",
    maintainer_email="clusterfem@example.com",
    description="Skeleton-driven soft bodies with clustered linear FEM for ROS 2.",
    license="Apache-2.0",
    extras_require={"test": ["pytest", "websockets", "mcap-ros2-support"], "robots": ["example-robot-data"]},
    entry_points={
        "console_scripts": [
            "clusterfem_demo = clusterfem_ros.nodes.demo:main",
            "clusterfem_node = clusterfem_ros.nodes.clusterfem_node:main",
            "mocap_player = clusterfem_ros.nodes.player_node:main",
        ],
    },
)
