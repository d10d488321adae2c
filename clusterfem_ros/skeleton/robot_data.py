"""Files named ``package://<package>/<path>`` (the way robot URDFs name themselves and their meshes), found in the
installed Python packages that ship ROS-style ``share/`` folders, such as example-robot-data's wheel.

``package_roots()`` lists the folders a package may be in: ``share/`` of every ``cmeel.prefix`` on
``sys.path`` (where cmeel wheels such as example-robot-data install), and ``share/`` of every prefix in
``$AMENT_PREFIX_PATH`` (a ROS install). ``package_file("package://example-robot-data/robots/panda_description/
urdf/panda.urdf")`` is that file, or None. Nothing is downloaded: a package that is not installed is not found.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

PACKAGE_SCHEME = "package://"
ROBOT_DATA = "example-robot-data"        # the pip package whose robots the robot scenes use


def package_roots() -> list[Path]:
    """Folders holding ``<package>/...``: cmeel's ``share/`` on sys.path, then $AMENT_PREFIX_PATH's ``share/``."""
    out: list[Path] = []
    for entry in sys.path:
        share = Path(entry or ".") / "cmeel.prefix" / "share"
        if share.is_dir() and share not in out:
            out.append(share)
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        share = Path(prefix) / "share" if prefix else None
        if share is not None and share.is_dir() and share not in out:
            out.append(share)
    return out


def package_file(name: str) -> Path | None:
    """The file a ``package://<package>/<path>`` name points to in the installed packages, or None (also for
    a name without that scheme)."""
    if not name.startswith(PACKAGE_SCHEME):
        return None
    rest = name[len(PACKAGE_SCHEME):]
    for root in package_roots():
        p = root / rest
        if p.is_file():
            return p
    return None


def robot_data_folder() -> Path | None:
    """example-robot-data's ``robots/`` folder when the package is installed, else None."""
    for root in package_roots():
        p = root / ROBOT_DATA / "robots"
        if p.is_dir():
            return p
    return None
