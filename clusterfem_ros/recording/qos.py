"""Offered QoS profiles in rosbag2's version-9 form (metadata.yaml list, MCAP channel YAML string)."""
from __future__ import annotations

import yaml

INFINITE = {"sec": 9223372036, "nsec": 854775807}  # RMW_DURATION_INFINITE, as rosbag2 (Jazzy) writes it
_PROFILES: dict[str, tuple[int, str, str]] = {
    # name: (depth, reliability, durability); history keep_last, liveliness automatic
    "reliable": (10, "reliable", "volatile"),
    "sensor_data": (5, "best_effort", "volatile"),
    "transient_local": (1, "reliable", "transient_local"),
}
QOS_NAMES: tuple[str, ...] = tuple(_PROFILES)


def qos_profile(name: str) -> dict:
    """One offered QoS profile as a plain dict (the items of `offered_qos_profiles`)."""
    if name not in _PROFILES:
        raise ValueError(f"unknown QoS {name!r}: choose one of {', '.join(QOS_NAMES)}")
    depth, reliability, durability = _PROFILES[name]
    return {"history": "keep_last", "depth": depth, "reliability": reliability, "durability": durability,
            "deadline": dict(INFINITE), "lifespan": dict(INFINITE), "liveliness": "automatic",
            "liveliness_lease_duration": dict(INFINITE), "avoid_ros_namespace_conventions": False}


def qos_yaml(profiles: list[dict]) -> str:
    """The MCAP channel metadata value `offered_qos_profiles`: the list as a YAML string."""
    return yaml.safe_dump(profiles, default_flow_style=False, sort_keys=False).strip()
