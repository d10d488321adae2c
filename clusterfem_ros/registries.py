"""A table of things by name, each registered once: the material models, motion sources, body kinds and output
streams are kept in these (fem/materials/registry.py, motion.py, scene_build.py, nodes/outputs.py), and the light
declarations a scene's configuration reads without loading any implementation (fem/materials/warping_models.py,
body_kinds.py, topics.py) too."""
from __future__ import annotations

import importlib
from collections.abc import Sequence
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

    def names(self, *first: str, but: tuple[str, ...] = ()) -> "Names":
        """The registered names as a live tuple-like view (``first`` before them, ``but`` left out): a parameter's
        choices that follow what is registered after the parameter table was made."""
        return Names(self, first, but)


class Names(Sequence):
    """``first`` and then the keys of a registry (but ``but``), read at each use; compares equal to the tuple."""

    def __init__(self, registry: dict, first: tuple[str, ...] = (), but: tuple[str, ...] = ()):
        self._registry, self._first, self._but = registry, tuple(first), tuple(but)

    def _names(self) -> tuple[str, ...]:
        return self._first + tuple(n for n in self._registry if n not in self._but and n not in self._first)

    def __getitem__(self, k):
        return self._names()[k]

    def __len__(self) -> int:
        return len(self._names())

    def __contains__(self, name) -> bool:
        return name in self._names()

    def __eq__(self, other) -> bool:
        return tuple(self) == tuple(other) if isinstance(other, Sequence) and not isinstance(other, str) else NotImplemented

    def __hash__(self):
        return hash(self._names())

    def __add__(self, other) -> tuple:
        return self._names() + tuple(other)

    def __radd__(self, other) -> tuple:
        return tuple(other) + self._names()

    def __repr__(self) -> str:
        return repr(self._names())


def load_object(path: str):
    """The object a ``'package.module:attribute'`` path names, its module imported now (a declaration's
    implementation, loaded when it is first used); ValueError naming the path when it does not resolve."""
    module, _, attribute = path.partition(":")
    if not module or not attribute:
        raise ValueError(f"implementation {path!r}: give it as 'package.module:attribute'")
    try:
        return getattr(importlib.import_module(module), attribute)
    except (ImportError, AttributeError) as exc:
        raise ValueError(f"implementation {path!r} does not load ({exc}): check the module and the name") from exc
