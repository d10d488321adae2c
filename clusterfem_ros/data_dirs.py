"""Where data that is not shipped (motion captures, character meshes, URDFs with their meshes) is looked for.

In order: ``$CLUSTERFEM_DATA``; the ``shared/data`` folder beside a source checkout (only when this package runs
from one: a checkout holds setup.py and package.xml above the package); the user data folder,
``~/.local/share/clusterfem_ros`` on Linux (``$XDG_DATA_HOME/clusterfem_ros`` when set; platformdirs' user data
folder on other systems). A name such as ``mocap/cmu_06_01_walk.bvh`` is looked up under each.
"""
from __future__ import annotations

import os
from pathlib import Path

DATA_ENV = "CLUSTERFEM_DATA"
APP_NAME = "clusterfem_ros"


def checkout_data() -> Path | None:
    """``<checkout>/../shared/data`` when the package runs from a source checkout, else None (an installed package
    has no such neighbour: under site-packages it would point into the environment's lib folder)."""
    root = Path(__file__).resolve().parents[1]
    if (root / "setup.py").is_file() and (root / "package.xml").is_file():
        return root.parent / "shared" / "data"
    return None


def user_data_dir() -> Path:
    from platformdirs import user_data_path
    return user_data_path(APP_NAME, appauthor=False)


def data_roots() -> list[Path]:
    """The folders searched for a data file given by name, in order."""
    roots = [Path(os.environ[DATA_ENV])] if os.environ.get(DATA_ENV) else []
    shared = checkout_data()
    return roots + ([shared] if shared is not None else []) + [user_data_dir()]
