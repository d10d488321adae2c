"""The real data beside the checkout (../shared/data), wherever the checkout is."""
from pathlib import Path

SHARED = Path(__file__).resolve().parents[2] / "shared"
CMU_WALK = SHARED / "data" / "mocap" / "cmu_06_01_walk.bvh"
