"""ROS 2 nodes: they wire topics and parameters to the core (clusterfem_ros.scene) and msg_adapters."""
