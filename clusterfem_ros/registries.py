"""A table of things by name, each registered once: the material models, motion sources, body kinds and output
streams are kept in these (fem/materials/registry.py, motion.py, scene_build.py, nodes/outputs.py)."""
from __future__ import annotations

from typing import TypeVar

T = TypeVar("T")


class Registry(dict):
    """{name: thing}; ``register`` refuses an empty or taken name, ``unregister`` a built-in one."""

    def __init__(self, what: str):
        super().__init__()
        self.what = what                # 'material model', 'motion source', ...: named in the refusals
        self.built_in: tuple[str, ...] = ()

    def register(self, name: str, thing: T) -> T:
        if not name or name in self:
            raise ValueError(f"{self.what} name {name!r} is empty or taken ({', '.join(sorted(self))})")
        self[name] = thing
        return thing

    def seal(self) -> None:
        """What is registered now is built in: ``unregister`` keeps it."""
        self.built_in = tuple(self)

    def unregister(self, name: str) -> None:
        """Remove what ``register`` added (a test's own); a built-in entry stays."""
        if name in self.built_in:
            raise ValueError(f"{name!r} is a built-in {self.what}")
        del self[name]
