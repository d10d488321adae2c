"""What each bone of a humanoid skeleton is (pelvis, spine, neck, head, arms, hands, legs, feet), from the tree
and its rest geometry; joint names are only hints. No unit is assumed: every test is a ratio.

``label_bones(names, parent, starts, ends)`` takes the bones in any order (``parent`` (nb,) index, -1 for a
root) and their rest segments ``starts``/``ends`` (nb, 3) (``Skeleton.bone_segments``: origin to tip or farthest
child) and decides, in order:

1. the five limb ends (both hands, both feet, the head): the leaf farthest along the tree from the root, then
   each time the leaf farthest along the tree from the paths already taken. Fingers, toes, eyes and props
   branch off near a limb's end, so they are short and come later;
2. which two pairs of ends are mirror limbs: a pair meets the rest of the body at one joint (or two close
   ones) and its two limbs are equally long; of the 15 ways to pair four of the five ends, the most symmetric
   wins and the end left over is the head. Of the two pairs the legs are the one whose ends lie farther from
   the head's end (in any standing rest pose, T or A, the feet are the far ends);
3. up (feet to head) and forward (the feet's horizontal reach, toes ahead of hips), so left = up x forward;
   each limb of a pair goes to the side its joints lie on. Without feet that point ahead, the names decide
   (``name_side``: ``Left``/``Right``, ``L``/``R``, ``l_``, ``_L``, ``.l``, ``lThigh``, ... any case, any prefix such as
   ``mixamorig:`` or ``Bip01``); the log line says which;
4. along each limb from where it meets the body: the two consecutive bones of greatest total length are the
   upper and lower limb (thigh and shin, upper arm and forearm); bones before them are the hip or clavicle,
   the next one the foot or hand, the rest toes or fingers. Along the trunk: bones from the root to where the
   legs meet are the pelvis (a long one from the floor up is a 'root' helper), up to where the arms meet the
   spine, then the neck, and the last bone with length the head. Bones in side branches take the role of the
   limb part they hang from (a finger's branches are fingers, an eye is part of the head).

``flesh_radii`` gives each role a capsule radius as a fraction of the skeleton's standing height (the default
humanoid's radii over its height), so the flesh has human proportions at any scale. Fingers, 'root' helpers
and bones of zero length stay bare (the hand's and the head's capsules cover them; a finger is thinner than the
voxels of a body of a few thousand tets).
"""
from __future__ import annotations

import itertools
import re
from dataclasses import dataclass, field

import numpy as np

from ..errors import ClusterFemError

LIMB_ROLES = {"leg": ("hip", "thigh", "shin", "foot", "toe"), "arm": ("clavicle", "upper_arm", "forearm", "hand",
                                                                          "finger")}
TRUNK_ROLES = ("root", "pelvis", "spine", "neck", "head")
BARE_ROLES = ("root", "finger")
_SIDE_WORDS = ("hip", "thigh", "upleg", "leg", "knee", "shin", "calf", "foot", "ankle", "toe", "collar", "clavicle",
               "shoulder", "shldr", "arm", "uparm", "forearm", "elbow", "wrist", "hand", "buttock", "finger", "thumb",
               "index", "mid", "ring", "pinky", "eye", "ear", "low", "up")


@dataclass
class BoneRoles:
    names: list[str]
    roles: list[str]                 # one of TRUNK_ROLES, LIMB_ROLES values, or 'head' for head parts
    sides: list[str]                 # 'l', 'r' or '' (trunk)
    height: float                    # standing height of the joints (feet to head end), input units
    up: np.ndarray                   # (3,) unit
    left: np.ndarray                 # (3,) unit
    sided_by: str                    # 'geometry' or 'names' (or 'arbitrary' when neither tells)
    lengths: np.ndarray              # (nb,) segment length of each bone, input units
    notes: list[str] = field(default_factory=list)

    def role_of(self, name: str) -> str:
        k = self.names.index(name)
        return (self.sides[k] + "_" if self.sides[k] else "") + self.roles[k]

    def summary(self) -> str:
        """One line: the bones of each role (by side), how left and right were told."""
        groups: dict[str, list[str]] = {}
        for n, r, s in zip(self.names, self.roles, self.sides):
            groups.setdefault((s + "_" if s else "") + r, []).append(n)
        main = [k for k in ("pelvis", "spine", "neck", "head", "l_thigh", "r_thigh", "l_upper_arm", "r_upper_arm",
                            "l_hand", "r_hand", "l_foot", "r_foot") if k in groups]
        return (f"bone roles from the skeleton's shape (height {self.height:.3g} units, sides by {self.sided_by}): "
                + "; ".join(f"{k} {', '.join(groups[k])}" for k in main))


class NotHumanoid(ClusterFemError, ValueError):
    """The tree has no two legs, two arms and a head; the message says what is missing."""


def name_side(name: str) -> str:
    """'l', 'r' or '' from a joint name: 'LeftUpLeg', 'mixamorig:RightHand', 'Bip01 L Thigh', 'l_knee', 'Hand_L',
    'thigh.R', 'LHipJoint', 'lShldr', 'rcollar' (any case); '' when the name says no side."""
    base = name.split(":")[-1]
    words = [w for w in re.split(r"[^A-Za-z]+|(?<=[a-z])(?=[A-Z])", base) if w]
    low = [w.lower() for w in words]
    for w in low:
        if w in ("l", "r"):
            return w
        if w.startswith(("left", "right")):     # 'Left', 'LEFTFOOT', 'leftupleg'
            return w[0]
    for w, lw in zip(words, low):            # 'LHipJoint' -> 'LHip', 'lshldr', 'rThigh'
        camel = len(w) > 2 and w[0] in "LR" and w[1].isupper() and w[2].islower()
        if lw[0] in "lr" and len(w) > 1 and (camel or lw[1:].startswith(_SIDE_WORDS)):
            return lw[0]
    return ""


def _depths(parent: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """(nb,) distance along the tree from the bone's root to each bone's origin."""
    nb = parent.size
    depth = np.full(nb, np.nan)
    for b in range(nb):
        chain = []
        c = b
        while c >= 0 and np.isnan(depth[c]):
            chain.append(c)
            c = parent[c]
        base = 0.0 if c < 0 else depth[c]
        for k in reversed(chain):
            p = parent[k]
            base = base + (np.linalg.norm(starts[k] - starts[p]) if p >= 0 else 0.0)
            depth[k] = base
    return depth


def _path(parent: np.ndarray, a: int, b: int) -> list[int]:
    """Bones on the tree path from a to b, both included."""
    up_a = [a]
    while parent[up_a[-1]] >= 0:
        up_a.append(int(parent[up_a[-1]]))
    seen = {c: k for k, c in enumerate(up_a)}
    up_b = [b]
    while up_b[-1] not in seen:
        up_b.append(int(parent[up_b[-1]]))
    return up_a[:seen[up_b[-1]] + 1] + up_b[-2::-1]


def label_bones(names: list[str], parent, starts, ends) -> BoneRoles:
    """The role and side of every bone (see the module docstring); NotHumanoid when the tree is not a human's."""
    parent = np.asarray(parent, dtype=np.int64)
    starts = np.asarray(starts, dtype=np.float64)
    ends = np.asarray(ends, dtype=np.float64)
    nb = len(names)
    if nb < 5 or parent.shape != (nb,) or starts.shape != (nb, 3) or ends.shape != (nb, 3):
        raise NotHumanoid(f"{nb} bones: a human skeleton has at least 5 (two arms, two legs, a head)")
    if (parent < 0).sum() != 1:
        raise NotHumanoid(f"{(parent < 0).sum()} root bones: a human skeleton is one tree")
    children = [[] for _ in range(nb)]
    for b, p in enumerate(parent):
        if p >= 0:
            children[p].append(b)
    leaves = [b for b in range(nb) if not children[b]]
    reach = np.linalg.norm(ends - starts, axis=1)          # a leaf's own length beyond its origin
    depth = _depths(parent, starts)
    anc = [set(_path(parent, b, int(np.flatnonzero(parent < 0)[0]))) for b in range(nb)]

    def tree_dist(a: int, b: int) -> float:
        common = anc[a] & anc[b]
        lca = max(common, key=lambda c: depth[c])
        return float(depth[a] + depth[b] - 2 * depth[lca])

    # 1. five limb ends, farthest-first along the tree
    root = int(np.flatnonzero(parent < 0)[0])
    dist_to_taken = np.array([tree_dist(root, b) for b in range(nb)])
    taken: set[int] = {root}
    limb_ends: list[int] = []
    gaps: list[float] = []
    for _ in range(5):
        cand = [b for b in leaves if b not in limb_ends]
        if not cand:
            raise NotHumanoid(f"{len(leaves)} leaf bones: a human skeleton has at least 5 (hands, feet, head)")
        score = [dist_to_taken[b] + reach[b] for b in cand]
        e = cand[int(np.argmax(score))]
        limb_ends.append(e)
        gaps.append(float(max(score)))
        new = set(_path(parent, e, root)) - taken
        taken |= new
        for n in new:
            for b in range(nb):
                dist_to_taken[b] = min(dist_to_taken[b], tree_dist(n, b))
    span = gaps[0]
    if gaps[4] < 0.05 * span:
        raise NotHumanoid(f"the fifth limb end ({names[limb_ends[4]]}) reaches only {gaps[4] / span:.2f} of the body's "
                          "span from the rest: the tree has fewer than two arms, two legs and a head")

    # 2. mirror pairs: where each end's path meets the others', how long its limb is
    def attach(e: int, others: list[int]) -> tuple[int, float]:
        """The bone where e's path to the root meets the paths of ``others``, and e's limb length from it."""
        other_nodes = set().union(*(set(_path(parent, o, root)) for o in others))
        for c in _path(parent, e, root):
            if c in other_nodes:
                return c, tree_dist(e, c) + reach[e]
        return root, tree_dist(e, root) + reach[e]

    def pair_cost(i: int, j: int, rest: list[int]) -> tuple[float, int, int]:
        """(asymmetry of the pair i, j: length difference plus the tree distance between where each meets the
        ``rest``, over their total length; where i meets the rest; where j does)."""
        ai, li = attach(i, rest)
        aj, lj = attach(j, rest)
        return (abs(li - lj) + tree_dist(ai, aj)) / (li + lj), ai, aj

    best = None
    for h in range(5):
        four = [e for k, e in enumerate(limb_ends) if k != h]
        for p1 in ((0, 1), (0, 2), (0, 3)):
            p2 = tuple(k for k in range(4) if k not in p1)
            a, b = [four[k] for k in p1], [four[k] for k in p2]
            ca = pair_cost(a[0], a[1], b + [limb_ends[h]])
            cb = pair_cost(b[0], b[1], a + [limb_ends[h]])
            total = ca[0] + cb[0]
            if best is None or total < best[0]:
                best = (total, limb_ends[h], a, b, ca, cb)
    _, head_end, pa, pb, ca, cb = best
    head_tip = ends[head_end]
    far_a = np.mean([np.linalg.norm(ends[e] - head_tip) for e in pa])
    far_b = np.mean([np.linalg.norm(ends[e] - head_tip) for e in pb])
    (legs, leg_att), (arms, arm_att) = ((pa, ca), (pb, cb)) if far_a >= far_b else ((pb, cb), (pa, ca))

    # 3. up, forward, left
    foot_tips = ends[legs]
    up = head_tip - foot_tips.mean(axis=0)
    height = float(np.linalg.norm(up))
    if height <= 0:
        raise NotHumanoid("the head's end and the feet coincide: the rest pose has no height")
    up = up / height
    hips = starts[[leg_att[1], leg_att[2]]].mean(axis=0)
    reach_fwd = foot_tips.mean(axis=0) - hips
    reach_fwd = reach_fwd - up * (reach_fwd @ up)
    notes = []
    if np.linalg.norm(reach_fwd) > 0.03 * height:
        forward = reach_fwd / np.linalg.norm(reach_fwd)
        left = np.cross(up, forward)
        sided_by = "geometry"
    else:
        left = None
        sided_by = "names"
    roles = [""] * nb
    sides = [""] * nb

    def limb(e: int, att: int) -> list[int]:
        """Bones from below the attachment bone to the end e, in order."""
        p = _path(parent, att, e)
        return p[1:]

    limbs = {}
    for kind, pair, att in (("leg", legs, leg_att), ("arm", arms, arm_att)):
        chains = [limb(pair[0], att[1]), limb(pair[1], att[2])]
        centre = [starts[c].mean(axis=0) for c in chains]
        if left is not None:
            d = float((centre[0] - centre[1]) @ left)
            if abs(d) < 0.02 * height:
                sided_by = "names"
        order = None
        if left is not None and sided_by == "geometry":
            order = (0, 1) if (centre[0] - centre[1]) @ left > 0 else (1, 0)
        if order is None:
            votes = [sum({"l": 1, "r": -1, "": 0}[name_side(names[b])] for b in c) for c in chains]
            if votes[0] != votes[1]:
                order = (0, 1) if votes[0] > votes[1] else (1, 0)
            else:
                order = (0, 1)
                sided_by = "arbitrary"
                notes.append(f"the {kind}s' sides are not told by their shape nor their names: "
                             f"{names[pair[0]]} taken as left")
        limbs[kind] = {"l": chains[order[0]], "r": chains[order[1]]}
    if sided_by == "names" and left is None:
        # left from the named sides of the legs
        left = starts[limbs["leg"]["l"]].mean(axis=0) - starts[limbs["leg"]["r"]].mean(axis=0)
        left = left - up * (left @ up)
        left = left / max(np.linalg.norm(left), 1e-12)

    # 4. roles along the limbs, on the bones with length (a zero-length bone takes the role of the next one)
    def lateral(points: np.ndarray, through: np.ndarray) -> np.ndarray:
        rel = points - through
        return np.linalg.norm(rel - np.outer(rel @ up, up), axis=1)

    for kind, by_side in limbs.items():
        first, upper, lower, end_role, tip_role = LIMB_ROLES[kind]
        for side, chain in by_side.items():
            solid = [b for b in chain if reach[b] > 1e-9 * height]
            if len(solid) < 2:
                raise NotHumanoid(f"the {side} {kind} ({', '.join(names[b] for b in chain)}) has {len(solid)} bone "
                                  "with length: a limb has an upper and a lower part")
            lengths = reach[solid]
            if kind == "leg":       # thigh and shin: the two consecutive bones of greatest total length
                k = int(np.argmax(lengths[:-1] + lengths[1:]))
            else:                   # upper arm: the first long bone that starts off the trunk (at the shoulder)
                off = lateral(starts[solid], starts[arm_att[1]])
                ok = [i for i in range(len(solid) - 1) if off[i] >= 0.06 * height and lengths[i] >= 0.08 * height]
                k = ok[0] if ok else int(np.argmax(lengths[:-1] + lengths[1:]))
            def role_at(i: int) -> str:
                return first if i < k else upper if i == k else lower if i == k + 1 else \
                    end_role if i == k + 2 else tip_role

            role_of = {b: role_at(i) for i, b in enumerate(solid)}
            pending = []
            for b in chain:
                pending.append(b)
                if b in role_of:
                    for c in pending:
                        roles[c], sides[c] = role_of[b], side
                    pending = []
            for c in pending:       # zero-length bones past the last one with length: the next part (a hand)
                roles[c], sides[c] = role_at(len(solid)), side
    # the trunk: root to the legs' meeting point is pelvis, up to the arms' is spine, then neck and head
    leg_hub, arm_hub = leg_att[1], arm_att[1]
    for b in _path(parent, root, leg_hub):
        roles[b] = "root" if reach[b] > 0.35 * height else "pelvis"     # a helper from the floor up
    trunk = _path(parent, root, head_end)
    spine_top = max((c for c in trunk if c in anc[arm_hub]), key=lambda c: depth[c])
    upper = [b for b in trunk if not roles[b]]
    head_chain = [b for b in upper if b not in anc[spine_top]]
    for b in upper:
        if b in anc[spine_top]:
            roles[b] = "spine"
    with_length = [k for k, b in enumerate(head_chain) if reach[b] > 1e-9 * height]
    last = with_length[-1] if with_length else len(head_chain) - 1
    for k, b in enumerate(head_chain):
        roles[b] = "neck" if k < last else "head"
    # side branches take their parent's role ('hand' parts below a hand are fingers, below a foot toes)
    for b in range(nb):
        if roles[b]:
            continue
        c = b
        while not roles[c]:
            c = int(parent[c])
        r = roles[c]
        roles[b] = {"hand": "finger", "foot": "toe", "toe": "toe", "finger": "finger"}.get(r, r)
        sides[b] = sides[c]
    ankles = [next(b for b in limbs["leg"][sd] if roles[b] == "foot") for sd in "lr"
              if any(roles[b] == "foot" for b in limbs["leg"][sd])]
    if ankles:                  # the toes reach forward: up is better measured from the ankles
        up = head_tip - starts[ankles].mean(axis=0)
        up = up / np.linalg.norm(up)
        left = left - up * (left @ up)
        left = left / max(np.linalg.norm(left), 1e-12)
        height = float(np.ptp(np.vstack([starts, ends]) @ up))
    return BoneRoles(list(names), roles, sides, height, up, left, sided_by, reach, notes)


def stands(roles: BoneRoles, vertical=(0.0, 0.0, 1.0)) -> bool:
    """Whether the labelled skeleton stands: its feet-to-head axis within 45 degrees of ``vertical``."""
    return float(roles.up @ np.asarray(vertical, dtype=np.float64)) >= np.cos(np.pi / 4)


def label_skeleton(skeleton, q: np.ndarray | None = None) -> BoneRoles:
    """``label_bones`` of a ``kinematics.Skeleton`` in its rest pose (q = 0) or in the configuration ``q``."""
    starts, ends = skeleton.bone_segments(skeleton.neutral() if q is None else q)
    return label_bones(skeleton.bone_names, skeleton.bone_parent, starts, ends)


def stands_in(skeleton, q: np.ndarray | None = None) -> tuple[bool, str]:
    """(whether a human stands in ``skeleton``'s configuration ``q`` (None: its zero pose), the reason in words):
    False with what is missing when the tree is no human's (NotHumanoid), else ``stands`` of its roles."""
    try:
        roles = label_skeleton(skeleton, q)
    except NotHumanoid as exc:
        return False, f"no human ({exc})"
    return stands(roles), f"feet to head along {np.round(roles.up, 2).tolist()}"


# capsule radius per role over the default humanoid's joint height (feet to the top of its head bone)
def _role_fractions() -> dict[str, float]:
    from .humanoid import BONE_RADIUS, PELVIS_HEIGHT
    skeleton_height = PELVIS_HEIGHT + 0.12 + 0.18 + 0.23 + 0.10 + 0.07
    r = dict(BONE_RADIUS)
    out = {"pelvis": r["pelvis"], "spine": r["abdomen"], "neck": r["neck"], "head": r["head"],
           "clavicle": r["clavicle"], "upper_arm": r["upper_arm"], "forearm": r["forearm"], "hand": r["hand"],
           "hip": r["thigh"], "thigh": r["thigh"], "shin": r["shin"], "foot": r["foot"], "toe": r["toes"]}
    return {k: v / skeleton_height for k, v in out.items()}


def flesh_radii(roles: BoneRoles, target_tets: int | None = None, voxels_across: float = 1.25
                ) -> tuple[dict[str, float], list[str]]:
    """({bone: capsule radius in the skeleton's units}, the bones left bare): radius = the role's fraction of the
    standing height; bare are the BARE_ROLES and bones of zero length that are not the pelvis (a zero-length pelvis
    is a ball where the legs and the spine meet). With ``target_tets``, no radius is below ``voxels_across`` voxel
    spacings of a body of that many tets (``voxel_spacing``): a hand one voxel thick is a flap that tears on the
    first fast turn."""
    frac = _role_fractions()
    radii, bare = {}, []
    for n, r, length in zip(roles.names, roles.roles, roles.lengths):
        if r in BARE_ROLES or r not in frac or (length <= 1e-9 * roles.height and r != "pelvis"):
            bare.append(n)
        else:
            radii[n] = frac[r] * roles.height
    if target_tets:
        lengths = dict(zip(roles.names, roles.lengths))
        for _ in range(3):                      # the floor thickens the body, which widens the voxels a little
            floor = voxels_across * voxel_spacing([lengths[n] for n in radii], list(radii.values()), target_tets)
            radii = {n: max(r, floor) for n, r in radii.items()}
    return radii, bare


def voxel_spacing(lengths, radii, target_tets: int) -> float:
    """The voxel spacing of a jelly body of about ``target_tets`` tets (five per voxel) around capsules of these
    lengths and radii, their volumes summed (overlaps counted twice: a slight overestimate)."""
    L, r = np.asarray(lengths, dtype=np.float64), np.asarray(radii, dtype=np.float64)
    volume = float(np.sum(np.pi * r ** 2 * L + 4.0 / 3.0 * np.pi * r ** 3))
    return (5.0 * volume / target_tets) ** (1.0 / 3.0)


__all__ = ["BoneRoles", "NotHumanoid", "flesh_radii", "label_bones", "label_skeleton", "name_side", "stands"]
