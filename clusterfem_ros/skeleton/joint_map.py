"""Mapping JointState-like inputs (names, positions, optional velocities) onto a skeleton's q and v by name.

Policy (what a node needs to warn well and keep running):

* a joint missing from a message keeps its last value (split publishers, partial messages);
* unknown names are reported once (one ``unknown_joint`` problem per message that brings new ones;
  ``JointMapResult.new_unknown`` lists them) and otherwise ignored; at most ``MAX_REMEMBERED_UNKNOWN``
  names are remembered, so a stream of ever new names cannot grow memory (beyond, they are reported again);
* fatal, the message is dropped (``accepted`` False): more than ``max_names`` names (``too_many_names``,
  before any per-name work), names and positions of different length (``length_mismatch``), a name given
  twice (``duplicate_joint``), no known joint at all (``no_known_joint``);
* repaired: a non-finite position leaves that joint at its last value (``non_finite``); velocities of
  the wrong length or with a non-finite entry are dropped (``bad_velocity``) and v is None;
* a mimic joint (``mimic``: the URDF's ``<mimic>`` tags) that a message leaves out while it sets its master
  follows the master: ``multiplier q_master + offset`` (robot drivers publish the master only).

v is returned only when the message gives a finite velocity for every skeleton joint; otherwise it is
None and the interpolator derives velocities by finite differences. Units: radians and metres (and /s).
Every check is linear in the message size.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

FATAL = frozenset({"too_many_names", "length_mismatch", "duplicate_joint", "no_known_joint"})
MAX_REMEMBERED_UNKNOWN = 1000
_SHOWN = 5          # names quoted in one message


@dataclass
class JointMapResult:
    """Outcome of one ``JointMap.update``: the new q (n,), v (n,) or None, and the problems found."""
    accepted: bool
    q: np.ndarray
    v: np.ndarray | None
    updated: np.ndarray                                     # (n,) bool: joints set by this message
    problems: list[tuple[str, str]] = field(default_factory=list)   # (kind, message)
    new_unknown: list[str] = field(default_factory=list)


class JointMap:
    """Holds the last known q of ``joint_names`` and merges JointState-like messages into it."""

    def __init__(self, joint_names: Sequence[str], q0: np.ndarray | None = None, max_names: int = 100_000,
                 mimic: dict[str, tuple[str, float, float]] | None = None):
        self.joint_names = list(joint_names)
        if len(set(self.joint_names)) != len(self.joint_names):
            dup = sorted({n for n in self.joint_names if self.joint_names.count(n) > 1})
            raise ValueError(f"joint names {dup} appear twice in the skeleton: joint names must be unique")
        self._index = {n: i for i, n in enumerate(self.joint_names)}
        n = len(self.joint_names)
        q0 = np.zeros(n) if q0 is None else np.asarray(q0, dtype=np.float64).copy()
        if q0.shape != (n,) or not np.isfinite(q0).all():
            raise ValueError(f"q0 must be {n} finite values (one per joint), got shape {q0.shape}")
        self.q = q0
        if max_names < 1:
            raise ValueError(f"max_names = {max_names} must be >= 1")
        self.max_names = int(max_names)
        self.unknown: set[str] = set()
        self._last_names: tuple | None = None     # (names, at, to) of the last message (_known)
        pairs = [(self._index[f], self._index[m], k, o) for f, (m, k, o) in (mimic or {}).items()
                 if f in self._index and m in self._index]
        self._mimic = tuple(np.array(c) for c in zip(*pairs)) if pairs else None    # follower, master, mult, offset

    def update(self, names: Sequence[str], positions, velocities=None) -> JointMapResult:
        """Merge one message; see the module docstring for what is kept, repaired or rejected."""
        names = names if isinstance(names, list) else list(names)
        if len(names) > self.max_names:
            return self._rejected("too_many_names", f"joint state has {len(names)} names (max_names "
                                  f"{self.max_names}): message dropped; raise input.max_names if this is real")
        pos = np.asarray(positions, dtype=np.float64).reshape(-1)
        vel = None if velocities is None else np.asarray(velocities, dtype=np.float64).reshape(-1)
        n = len(self.joint_names)
        reject = self._rejected
        if pos.size != len(names):
            return reject("length_mismatch", f"joint state has {len(names)} names but {pos.size} positions: "
                          "send one position per name (message dropped)")
        if len(set(names)) != len(names):
            seen: set[str] = set()
            dup = sorted({x for x in names if x in seen or seen.add(x)})
            return reject("duplicate_joint", f"joint state names {dup[:_SHOWN]} more than once: send each joint "
                          "once (message dropped)")
        problems: list[tuple[str, str]] = []
        new_unknown = [x for x in names if x not in self._index and x not in self.unknown]
        if new_unknown:
            room = MAX_REMEMBERED_UNKNOWN - len(self.unknown)
            self.unknown.update(new_unknown[:max(room, 0)])
            more = f" and {len(new_unknown) - _SHOWN} more" if len(new_unknown) > _SHOWN else ""
            problems.append(("unknown_joint", f"joints {new_unknown[:_SHOWN]}{more} are not in the skeleton ({n} "
                                              "joints): ignored (reported once per name)"))
        at, to = self._known(names)
        if not at.size:
            out = reject("no_known_joint", f"joint state names none of the skeleton's joints (got {names[:_SHOWN]}): "
                         "check the publisher's joint names against the URDF (message dropped)")
            out.problems = problems + out.problems
            out.new_unknown = new_unknown
            return out
        if vel is not None and vel.size not in (0, len(names)):
            problems.append(("bad_velocity", f"joint state has {len(names)} names but {vel.size} velocities: "
                                             "velocities ignored, derived from positions instead"))
            vel = None
        elif vel is not None and vel.size and not np.isfinite(vel).all():
            k = int(np.flatnonzero(~np.isfinite(vel))[0])
            problems.append(("bad_velocity", f"joint {names[k]!r} velocity is {vel[k]}: velocities ignored, "
                                             "derived from positions instead; send finite values"))
            vel = None
        if vel is not None and vel.size == 0:
            vel = None
        updated = np.zeros(n, dtype=bool)
        q = self.q.copy()
        finite = np.isfinite(pos[at])
        q[to[finite]] = pos[at[finite]]
        updated[to[finite]] = True
        for k in at[~finite]:
            problems.append(("non_finite", f"joint {names[k]!r} position is {pos[k]} at index {k}: kept its "
                                           "last value; drop the sample or send a finite value"))
        if not updated.any():
            return JointMapResult(False, self.q.copy(), None, updated, problems, new_unknown)
        follow = None
        if self._mimic is not None:
            f, m, k, o = self._mimic
            follow = ~updated[f] & updated[m]
            q[f[follow]] = k[follow] * q[m[follow]] + o[follow]
            updated[f[follow]] = True
        v = None
        if vel is not None and updated.all():
            v = np.zeros(n)
            v[to] = vel[at]
            if follow is not None:
                v[f[follow]] = k[follow] * v[m[follow]]
        self.q = q
        return JointMapResult(True, q.copy(), v, updated, problems, new_unknown)

    def _known(self, names: list[str]) -> tuple[np.ndarray, np.ndarray]:
        """(positions in the message, indices in the skeleton) of the skeleton's joints a message names. A
        publisher sends the same names in the same order every time: the last answer is kept for them."""
        if self._last_names is None or self._last_names[0] != names:
            pairs = [(k, self._index[x]) for k, x in enumerate(names) if x in self._index]
            at = np.array([k for k, _ in pairs], dtype=np.int64)
            to = np.array([i for _, i in pairs], dtype=np.int64)
            self._last_names = (list(names), at, to)
        return self._last_names[1], self._last_names[2]

    def _rejected(self, kind: str, text: str) -> JointMapResult:
        n = len(self.joint_names)
        return JointMapResult(False, self.q.copy(), None, np.zeros(n, dtype=bool), [(kind, text)])
