"""Mapping JointState-like inputs (names, positions, optional velocities) onto a skeleton's q and v by name.

Policy (what a node needs to warn well and keep running):

* a joint missing from a message keeps its last value (split publishers, partial messages);
* unknown names are reported once (one ``unknown_joint`` problem per message that brings new ones;
  ``JointMapResult.new_unknown`` lists them) and otherwise ignored; at most ``MAX_REMEMBERED_UNKNOWN``
  names are remembered, so a stream of ever new names cannot grow memory (beyond, they are reported again);
* fatal, the message is dropped (``accepted`` False): more than ``max_names`` names (``too_many_names``,
  before any per-name work), names and positions of different length (``length_mismatch``), a name given
  twice (``duplicate_joint``), no known joint at all (``no_known_joint``);
* repaired: a non-finite position leaves that joint at its last value (``non_finite``), and so does one
  outside the joint's URDF range widened by its margin (``joint_range``, one problem per message naming the
  joints; ``limits``, see skeleton/joint_limits.py); velocities of the wrong length or with a non-finite entry
  are dropped (``bad_velocity``) and v is None;
* with ``limits``: continuous and full-turn revolute joints are wrapped to [-pi, pi) (the joint stream
  unwraps them), and a mimic joint the message does not name follows its master when the master moves.

v is returned only when the message gives a finite velocity for every skeleton joint; otherwise it is
None and the interpolator derives velocities by finite differences. Units: radians and metres (and /s).
Every check is linear in the message size.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from .joint_limits import JointLimits

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
                 limits: JointLimits | None = None):
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
        if limits is not None and not (limits.lower.shape == limits.upper.shape == limits.wrap.shape == (n,)):
            raise ValueError(f"limits are for {limits.lower.shape} joints, expected ({n},)")
        self.limits = limits
        self.unknown: set[str] = set()
        self._last_names: tuple | None = None     # (names, at, to) of the last message (_known)

    def update(self, names: Sequence[str], positions, velocities=None) -> JointMapResult:
        """Merge one message and keep its q; see the module docstring for what is kept, repaired or rejected."""
        result = self.merge(names, positions, velocities)
        if result.accepted:
            self.commit(result.q)
        return result

    def commit(self, q: np.ndarray) -> None:
        """Keep ``q`` (a ``merge`` result's) as the last known values: what the next message is merged into. A
        scene commits a sample only once its joint stream took it in, so a refused sample leaves no trace."""
        self.q = np.array(q, dtype=np.float64)

    def merge(self, names: Sequence[str], positions, velocities=None) -> JointMapResult:
        """The message merged into the last known values, which stay as they are (``commit`` keeps the result);
        see the module docstring for what is kept, repaired or rejected."""
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
        values = pos[at]
        finite = np.isfinite(values)
        taken = finite
        lim = self.limits
        if lim is not None:
            with np.errstate(invalid="ignore"):
                turn = np.remainder(values, 2.0 * np.pi)       # exact: no pi added to a huge angle first
                values = np.where(lim.wrap[to], np.where(turn >= np.pi, turn - 2.0 * np.pi, turn), values)
                taken = finite & (values >= lim.lower[to]) & (values <= lim.upper[to])
        q[to[taken]] = values[taken]
        updated[to[taken]] = True
        for k in at[~finite]:
            problems.append(("non_finite", f"joint {names[k]!r} position is {pos[k]} at index {k}: kept its "
                                           "last value; drop the sample or send a finite value"))
        if lim is not None and (finite & ~taken).any():
            out = np.flatnonzero(finite & ~taken)
            more = f" and {out.size - _SHOWN} more" if out.size > _SHOWN else ""
            shown = ", ".join(f"{names[at[i]]!r} = {values[i]:.6g} (taken in [{lim.lower[to[i]]:.6g}, "
                              f"{lim.upper[to[i]]:.6g}])" for i in out[:_SHOWN])
            problems.append(("joint_range", f"joint {shown}{more} outside the URDF limits and input."
                                            "joint_limit_margin: kept the last value; fix the publisher or the "
                                            "URDF limits"))
        followers = []                  # mimic joints set from their master by this message
        if lim is not None and lim.mimic:
            named = np.zeros(n, dtype=bool)
            named[to] = True
            for k, master, mul, off in lim.mimic:
                if updated[master] and not named[k]:
                    q[k] = mul * q[master] + off
                    updated[k] = True
                    followers.append((k, master, mul))
        if not updated.any():
            return JointMapResult(False, self.q.copy(), None, updated, problems, new_unknown)
        v = None
        if vel is not None and updated.all():
            v = np.zeros(n)
            v[to] = vel[at]
            for k, master, mul in followers:
                v[k] = mul * v[master]
        return JointMapResult(True, q, v, updated, problems, new_unknown)

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
