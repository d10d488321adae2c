"""The bind pose of a humanoid skeleton in a humanoid mesh, found from the two alone (``skeleton.bind_pose 'auto'``).

A character mesh is modelled in some pose (T-pose, A-pose, arms down) and a capture's skeleton stands in its own
(its rest: the zero pose, or frame 0 when no human stands in that). The steps:

1. **The mesh's limbs** (``mesh_pose``): on the closed surface (subdivided so that its edges are short), the five
   extremities are the farthest points along the surface from each other (farthest-point sampling of geodesic
   distance from the body's centre): the highest is the head, the two lowest the feet, the others the hands.
   Each limb is the part of the surface nearer its extremity than the other three limbs' (where two touch).
   From the extremity, the rings of equal geodesic distance go round the limb; their centroids trace the limb's
   middle (a level-set skeleton). The skeleton's own lengths say which ring is the wrist / ankle (the first whose
   centroid lies the hand's / foot's length from the tip: at least HAND_FOREARM of the forearm, a rig's hand that
   ends at the palm is no hand's length), the elbow / knee and the upper limb; the line through
   a bone's ring centroids is its direction in the mesh. The feet point the way the mesh faces: each foot's
   long axis below its ankle (its vertices' principal direction across the floor), turned towards its toe tip;
   the tip alone is no direction, as the farthest vertex of a rounded toe lies anywhere round its rim (the
   declared ``skeleton.fit_forward`` only when the toes lie too near the ankles to tell).
2. **The skeleton's trunk and limbs** (``straighten_trunk``, ``turn_limbs``): roles from the tree and the rest
   geometry (skeleton/bone_roles.py); the mesh is turned about the vertical to face the skeleton's way. A trunk
   leaning more than TRUNK_LEAN is stood up as the mesh stands (hips to shoulders, shoulders to the head's end
   along the vertical, least squares on the pelvis, spine, neck and head joints): a rest taken from a capture's
   frame leans as the motion does there. Then each limb's upper and lower bone is turned onto the mesh's
   directions by least squares on the joints of those two bones, then the hand / foot towards the mesh's tip.
   The clavicles and the hip bones keep the rest's angles (the capture plays its own on them: a girdle turned
   at bind time would move the shoulder or hip under the flesh on every frame).
3. **The placement**: scale and offset put the mesh's elbows, wrists, knees and ankles nearest the skeleton's
   (least squares), then the mesh is moved (fit.refine_fit, not scaled) until the bones that bind lie under its
   skin.
4. **What binds** (``bones_to_unbind``): after the fit (body/fit.py), finger, toe and root-helper bones (by role)
   with a point outside the mesh are left unbound: their flesh follows the hand, foot or pelvis; so are the
   head's side parts (eyes, a jaw: ``head_parts``), whose flesh follows the head.

``limb_report`` gives, per limb, how far the bones lie from the limb's middle (one log line).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .fit import FitError

LIMBS = (("l", "arm"), ("r", "arm"), ("l", "leg"), ("r", "leg"))
LIMB_NAMES = {("l", "arm"): "left arm", ("r", "arm"): "right arm", ("l", "leg"): "left leg", ("r", "leg"): "right leg"}
EDGE_FRACTION = 0.012       # the surface is subdivided to edges below this fraction of its height
BAND_FRACTION = 0.012       # half-width of a ring of equal geodesic distance, as a fraction of the height
RINGS = 6                   # ring centroids fitted per bone
UPPER_SPAN = (0.25, 0.6)    # the part of an upper limb whose rings are used (the top meets the trunk)
LOWER_SPAN = (0.2, 0.8)
REGULARIZE = 0.01           # weight of the joints' change in the least squares (keeps the twist)
UNBIND_MARGIN = 0.005       # [m] a finger or toe bone this far outside the skin binds no flesh
UNBINDABLE_ROLES = ("finger", "toe", "root")   # a 'root' helper: a bone from the floor up to the pelvis
HAND_FOREARM = 0.7          # a human's hand (wrist to fingertip) is about 0.74 of the forearm (Drillis & Contini)
TRUNK_LEAN = 15.0           # [deg] a rest whose hips-to-shoulders line leans more than this is stood up
HIP_RATIO = 0.53            # a human's hip joints stand this share of the stature above the soles (Drillis & Contini)


@dataclass
class MeshLimb:
    tip: np.ndarray             # (3,) the extremity (fingertip, toe tip)
    end: np.ndarray             # (3,) wrist / ankle: the ring centroid at the skeleton's hand / foot length
    middle_joint: np.ndarray    # (3,) elbow / knee
    upper_dir: np.ndarray       # (3,) unit, root to middle joint
    lower_dir: np.ndarray       # (3,) unit, middle joint to end
    middle: np.ndarray          # (k, 3) ring centroids from the end to the upper limb's top (the limb's middle)


@dataclass
class MeshPose:
    limbs: dict                 # (side, kind) -> MeshLimb
    head: np.ndarray            # (3,)
    up: np.ndarray              # (3,) unit, ankles to head
    forward: np.ndarray         # (3,) unit
    left: np.ndarray            # (3,) unit
    forward_by: str             # 'the feet' or the declared axis
    notes: list[str] = field(default_factory=list)

    def angles(self) -> dict[str, float]:
        """Degrees: each arm below the horizontal, each elbow's and knee's bend, each leg out from the vertical."""
        out = {}
        for side in "lr":
            arm, leg = self.limbs[(side, "arm")], self.limbs[(side, "leg")]
            out[f"{side}_arm_down"] = float(np.degrees(np.arcsin(np.clip(-arm.upper_dir @ self.up, -1, 1))))
            out[f"{side}_elbow"] = _angle(arm.upper_dir, arm.lower_dir)
            out[f"{side}_knee"] = _angle(leg.upper_dir, leg.lower_dir)
            out[f"{side}_leg_out"] = _angle(leg.upper_dir, -self.up)
        return out

    def describe(self) -> str:
        a = self.angles()
        down = 0.5 * (a["l_arm_down"] + a["r_arm_down"])
        name = "T-pose" if down < 20 else "A-pose" if down < 65 else "arms down"
        return (f"the mesh stands in {'a' if name == 'T-pose' else 'an'} {name}" if name != "arms down"
                else "the mesh stands with its arms down") + (
            f": arms {a['l_arm_down']:.0f} / {a['r_arm_down']:.0f} deg below the horizontal (left / right), elbows "
            f"bent {a['l_elbow']:.0f} / {a['r_elbow']:.0f} deg, legs {a['l_leg_out']:.0f} / {a['r_leg_out']:.0f} deg "
            f"from the vertical, knees bent {a['l_knee']:.0f} / {a['r_knee']:.0f} deg; facing from {self.forward_by}")


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)), -1.0, 1.0))))


def _unit(v: np.ndarray) -> np.ndarray:
    return v / max(float(np.linalg.norm(v)), 1e-12)


@dataclass(frozen=True)
class SkeletonLimb:
    upper: int                  # bone index of the upper arm / thigh
    lower: int                  # forearm / shin
    root: np.ndarray            # (3,) shoulder / hip joint
    middle: np.ndarray          # (3,) elbow / knee
    end: np.ndarray             # (3,) wrist / ankle
    tip_length: float           # wrist / ankle to the farthest end of the hand / foot bones, a hand at least
                                # HAND_FOREARM of the forearm [m]
    distal: int = -1            # the hand / foot bone (-1: none with length)
    tip_rise: float = 0.0       # how far the wrist / ankle lies above that farthest end along world Z [m]


def skeleton_limbs(roles, starts: np.ndarray, ends: np.ndarray) -> dict:
    """(side, kind) -> SkeletonLimb from bone_roles.BoneRoles of the skeleton posed with these segments."""
    out = {}
    for side, kind in LIMBS:
        upper_role, lower_role = ("upper_arm", "forearm") if kind == "arm" else ("thigh", "shin")
        distal = ("hand", "finger") if kind == "arm" else ("foot", "toe")
        solid = [b for b, (r, s) in enumerate(zip(roles.roles, roles.sides))
                 if s == side and roles.lengths[b] > 1e-9 * roles.height]
        ups = [b for b in solid if roles.roles[b] == upper_role]
        lows = [b for b in solid if roles.roles[b] == lower_role]
        if not ups or not lows:
            raise FitError(f"the skeleton's {LIMB_NAMES[(side, kind)]} has no {upper_role} and {lower_role} with "
                           "length: the skeleton is not a humanoid the bind pose can be found for; set "
                           "skeleton.bind_pose 'neutral' or 'first_frame'")
        u, lo = ups[0], lows[0]
        tips = [ends[b] for b, (r, s) in enumerate(zip(roles.roles, roles.sides)) if s == side and r in distal]
        wrist = ends[lo]
        far = max(tips, key=lambda t: float(np.linalg.norm(t - wrist)), default=wrist)
        reach = float(np.linalg.norm(far - wrist))
        if kind == "arm":       # a hand whose bones end at the palm (an end site, no fingers) is a human's length
            reach = max(reach, HAND_FOREARM * float(np.linalg.norm(ends[lo] - starts[lo])))
        hands = [b for b in solid if roles.roles[b] == distal[0]]
        out[(side, kind)] = SkeletonLimb(u, lo, starts[u].copy(), ends[u].copy(), wrist.copy(), reach,
                                         hands[0] if hands else -1, float(wrist[2] - far[2]))
    return out


def _subdivided(vertices: np.ndarray, triangles: np.ndarray, max_edge: float):
    import trimesh
    v, f = trimesh.remesh.subdivide_to_size(np.asarray(vertices, dtype=np.float64), np.asarray(triangles),
                                            max_edge=max_edge, max_iter=8)
    mesh = trimesh.Trimesh(v, f, process=True)         # merge the split edges' duplicate vertices
    return np.asarray(mesh.vertices), np.asarray(mesh.faces), mesh


def _graph(mesh):
    from scipy.sparse import coo_matrix
    e = np.asarray(mesh.edges_unique)
    w = np.asarray(mesh.edges_unique_length)
    n = len(mesh.vertices)
    return coo_matrix((np.r_[w, w], (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(n, n)).tocsr()


def _ring_centroid(x: np.ndarray, g: np.ndarray, d: float, band: float, graph=None, near=None) -> np.ndarray | None:
    """Centroid of the vertices ``band`` either side of geodesic distance ``d``; with ``graph``, of the connected
    piece of them whose centroid is nearest ``near`` (where the limbs touch, a ring of one thigh goes on across to
    the other: the piece on this limb is the one by the ring before)."""
    sel = np.flatnonzero(np.abs(g - d) < band)
    if sel.size < 3:
        return None
    if graph is None or near is None:
        return _trimmed_centre(x[sel])
    from scipy.sparse.csgraph import connected_components
    n, label = connected_components(graph[sel][:, sel], directed=False)
    pieces = [x[sel[label == k]] for k in range(n) if (label == k).sum() >= 3]
    if not pieces:
        return None
    return min((_trimmed_centre(p) for p in pieces), key=lambda c: float(np.linalg.norm(c - near)))


def _trimmed_centre(points: np.ndarray) -> np.ndarray:
    """The centre of a ring's points without the few that run on across a contact onto the next limb: the mean of
    the points within 1.6 times the median distance of the coordinate-wise median."""
    c = np.median(points, axis=0)
    r = np.linalg.norm(points - c, axis=1)
    return points[r <= 1.6 * np.median(r)].mean(axis=0)


def _line_direction(points: list[np.ndarray]) -> np.ndarray | None:
    """Unit direction of the line through ``points`` (first to last), by principal axis."""
    p = np.array([q for q in points if q is not None])
    if len(p) < 2:
        return None
    c = p - p.mean(axis=0)
    d = np.linalg.svd(c, full_matrices=False)[2][0]
    return d if d @ (p[-1] - p[0]) >= 0 else -d


def _limb_from_tip(x, g, tip, limb: SkeletonLimb, band: float, graph=None, by_height: bool = False) -> MeshLimb:
    """The mesh's limb traced from its extremity (geodesic distances ``g`` from it, over ``graph``; Z up), at the
    skeleton's lengths; ``by_height``: a leg (its ankle found by height above the toe tip)."""
    L_low = float(np.linalg.norm(limb.end - limb.middle))
    L_up = float(np.linalg.norm(limb.middle - limb.root))
    near = np.asarray(tip, dtype=np.float64)

    def ring(d: float):
        nonlocal near
        c = _ring_centroid(x, g, d, band, graph, near)
        if c is not None:
            near = c
        return c

    # the wrist ring: the first whose centroid lies the skeleton's hand length from the fingertip (a path along the
    # surface runs round the fingertip's cap first: past it, it runs along the limb's middle); the ankle ring: the
    # first whose centroid lies as high above the toe tip as the skeleton's ankle above its toes' end (feet differ
    # in length from subject to subject more than ankles in height: a capture's toe end site is no toe tip)
    d_end = limb.tip_length
    for d in np.arange(0.5 * band, 3.0 * limb.tip_length + 10 * band, 0.5 * band):
        c = ring(d)
        if c is not None and (c[2] - tip[2] >= limb.tip_rise if by_height else
                              np.linalg.norm(c - tip) >= limb.tip_length):
            d_end = float(d)
            break
    d_mid = d_end + L_low
    end = ring(d_end)
    low = [ring(d) for d in d_end + L_low * np.linspace(*LOWER_SPAN, RINGS)]
    mid = ring(d_mid)
    up = [ring(d) for d in d_mid + L_up * np.linspace(*UPPER_SPAN, RINGS)]
    lower_dir = _line_direction(low[::-1])          # middle joint -> end
    upper_dir = _line_direction(up[::-1])           # root -> middle joint
    if lower_dir is None or upper_dir is None or end is None or mid is None:
        raise FitError(f"the mesh's limb from the extremity at {np.round(tip, 3).tolist()} is shorter than the "
                       f"skeleton's ({d_end + L_low + L_up:.2f} m from its tip): the mesh's unit "
                       "(body.surface_unit) or the skeleton's (the capture's unit) is wrong")
    middle = np.array([c for c in [end] + low + [mid] + up if c is not None])
    return MeshLimb(np.asarray(tip), end, mid, upper_dir, lower_dir, middle)


def mesh_pose(vertices: np.ndarray, triangles: np.ndarray, limbs: dict, declared_forward: np.ndarray,
              height: float | None = None) -> MeshPose:
    """The pose of a standing humanoid mesh (``vertices`` in metres, Z up, roughly the skeleton's size) whose limbs
    are as long as the skeleton's ``limbs`` (skeleton_limbs); ``declared_forward`` (3,) is used only when the
    feet do not show which way the mesh faces. Raises FitError naming the input to check."""
    from scipy.sparse.csgraph import connected_components, dijkstra
    v = np.asarray(vertices, dtype=np.float64)
    h = float(np.ptp(v[:, 2])) if height is None else float(height)
    x, _, mesh = _subdivided(v, triangles, EDGE_FRACTION * h)
    graph = _graph(mesh)
    n_parts, label = connected_components(graph, directed=False)
    main = np.bincount(label).argmax()
    keep = label == main
    seed = int(np.argmin(np.where(keep, np.linalg.norm(x - x[keep].mean(axis=0), axis=1), np.inf)))
    dist = [dijkstra(graph, indices=seed)]
    picked: list[int] = []
    for _ in range(5):
        nearest = np.min(dist, axis=0)
        nearest[~keep | ~np.isfinite(nearest)] = -1.0
        k = int(np.argmax(nearest))
        picked.append(k)
        dist.append(dijkstra(graph, indices=k))
    geo = dict(zip(picked, dist[1:]))
    z = x[picked, 2]
    order = np.argsort(z)
    feet, head = [picked[i] for i in order[:2]], picked[order[-1]]
    hands = [picked[i] for i in order[2:4]]
    lo = float(x[keep, 2].min())
    if float(x[head, 2] - x[feet, 2].mean()) < 0.6 * h or max(x[feet, 2]) - lo > 0.25 * h:
        raise FitError(f"the mesh's extremities ({np.round(x[picked], 2).tolist()}) are not two feet at its bottom "
                       "and a head at its top: it does not stand along the declared up axis; check skeleton.fit_up")
    band = BAND_FRACTION * h
    # each limb: the vertices nearer to its extremity along the surface than to the other three limbs' (where two
    # limbs touch, the rings of one would otherwise go on across onto the other; the head is no limb's rival: the
    # top of an arm is nearer to it than to the hand)
    tips = feet + hands
    owner = np.argmin(np.array([geo[t] for t in tips]), axis=0)
    geo = {**geo, **{t: np.where(owner == k, geo[t], np.inf) for k, t in enumerate(tips)}}
    leg_of = {f: _limb_from_tip(x, geo[f], x[f], limbs[("l", "leg")], band, graph, by_height=True) for f in feet}
    ankles = np.mean([leg_of[f].end for f in feet], axis=0)
    up = _unit(x[head] - ankles)
    toes = np.mean([x[f] - leg_of[f].end for f in feet], axis=0)
    toes = toes - up * (toes @ up)
    if np.linalg.norm(toes) > 0.03 * h:
        # the feet tell (their tips lie that far ahead of the ankles); the way they point: each foot's long axis
        # below its ankle, towards its tip (the farthest vertex of a rounded toe may lie anywhere round its rim)
        axes = []
        for f in feet:
            p = x[np.isfinite(geo[f]) & (x[:, 2] < leg_of[f].end[2])]
            p = p - up * (p @ up)[:, None]
            if len(p) < 3:                       # no foot below the ankle to take an axis of: its tip's way
                axes.append(_unit(x[f] - leg_of[f].end))
                continue
            axis = np.linalg.svd(p - p.mean(axis=0), full_matrices=False)[2][0]
            axes.append(axis if axis @ toes > 0 else -axis)
        foot = np.mean(axes, axis=0)
        foot = foot - up * (foot @ up)
        forward, forward_by = _unit(foot), "the feet"
    else:
        forward, forward_by = _unit(declared_forward - up * (declared_forward @ up)), "skeleton.fit_forward"
    left = np.cross(up, forward)
    notes = []
    if forward_by == "the feet" and forward @ declared_forward < 0:
        notes.append("the mesh's toes point against skeleton.fit_forward: the mesh is taken to face its feet's way")
    ls = {}
    for kind, tips in (("leg", feet), ("arm", hands)):
        a, b = sorted(tips, key=lambda t: -(x[t] @ left))     # left first
        for side, t in (("l", a), ("r", b)):
            ls[(side, kind)] = leg_of[t] if kind == "leg" else _limb_from_tip(x, geo[t], x[t], limbs[(side, kind)],
                                                                             band, graph)
    if n_parts > 1:
        notes.append(f"the surface has {n_parts} pieces: the limbs are traced on the largest")
    return MeshPose(ls, x[head], up, forward, left, forward_by, notes)


def facing_rotation(pose: MeshPose, roles) -> np.ndarray:
    """(3, 3): the turn about the vertical (world Z: the mesh's declared up, the standing skeleton's) that makes the
    mesh face the skeleton's way (bone_roles' left, level). The tilts of the two are left alone: a point at the top
    of the head, where the mesh's up is measured to, lies off its axis by some degrees."""
    z = np.array([0.0, 0.0, 1.0])
    left_s = _unit(roles.left - z * (roles.left @ z))
    fwd_s = np.cross(left_s, z)
    fwd_m = _unit(pose.forward - z * (pose.forward @ z))
    left_m = np.cross(z, fwd_m)
    return np.column_stack([fwd_s, left_s, z]) @ np.column_stack([fwd_m, left_m, z]).T


def trunk_lean(skeleton, q: np.ndarray, roles) -> tuple[float, float]:
    """Degrees from the vertical (world Z) of the skeleton's trunk at ``q``: the line from its hip joints' centre
    to its shoulder joints' centre, and the line from there to the head's end."""
    s, e = skeleton.bone_segments(q)
    hips, shoulders, head = _trunk_points(roles, s, e)
    z = np.array([0.0, 0.0, 1.0])
    return _angle(shoulders - hips, z), _angle(head - shoulders, z)


def _trunk_points(roles, starts: np.ndarray, ends: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(hip joints' centre, shoulder joints' centre, the head's end): the thighs' and upper arms' starts, the end of
    the highest-reaching head bone."""
    limbs = skeleton_limbs(roles, starts, ends)
    hips = 0.5 * (limbs[("l", "leg")].root + limbs[("r", "leg")].root)
    shoulders = 0.5 * (limbs[("l", "arm")].root + limbs[("r", "arm")].root)
    heads = [ends[b] for b, r in enumerate(roles.roles) if r in ("head", "neck")]
    head = max(heads, key=lambda x: float(x[2])) if heads else shoulders + np.array([0.0, 0.0, 1.0])
    return hips, shoulders, head


def straighten_trunk(skeleton, q0: np.ndarray, roles) -> np.ndarray:
    """``q0`` with the trunk's joints (the pelvis, spine, neck and head bones' revolute joints) set by least squares
    so that the trunk stands as a mesh's does: the hips' centre to the shoulders' centre, and the shoulders' centre
    to the head's end, along the vertical (world Z, the fitted mesh's up). A capture bound on one of its frames
    (its zero pose lying down) leans as the motion does there (Bandai Namco's dash: the chest 48 deg forward, the
    shoulders 20 cm before the mesh's), and its limbs, turned onto the mesh's, would then hang off the trunk's
    flesh. Only a rest leaning more than TRUNK_LEAN is stood up (auto_bind_pose): a rig's own zero pose is the
    better guess of its trunk's shape than the vertical (CMU's on mesh2motion's T-pose: stood up, its legs land
    2 cm further from the mesh's). The limbs are turned after, from where this leaves them."""
    from scipy.optimize import least_squares
    owned = skeleton.bone_joints()
    revolute = skeleton.revolute_mask()
    joints = sorted({j for b, r in enumerate(roles.roles) if r in ("pelvis", "spine", "neck", "head")
                     for j in owned[b] if revolute[j]})
    q = np.asarray(q0, dtype=np.float64).copy()
    if not joints:
        return q
    x0 = q[joints].copy()
    z = np.array([0.0, 0.0, 1.0])

    def residual(xs: np.ndarray) -> np.ndarray:
        qq = q.copy()
        qq[joints] = xs
        hips, shoulders, head = _trunk_points(roles, *skeleton.bone_segments(qq))
        return np.concatenate([_unit(shoulders - hips) - z, _unit(head - shoulders) - z, REGULARIZE * (xs - x0)])

    q[joints] = least_squares(residual, x0, diff_step=1e-6, max_nfev=200 * len(joints)).x
    return q


def _standing_feet(rest: dict, upright: dict) -> dict:
    """The ``rest`` limbs (skeleton_limbs) with each leg's ``tip_rise`` (the ankle's height above the foot's far end,
    at which the mesh's ankle is traced) taken from the pose whose shin stands nearer the vertical: the rest, or
    ``upright``, the rest with its trunk stood up (straighten_trunk). A capture's frame bound as the rest
    (Bandai Namco's dash, mid-stride) has a foot pointed off the ground or a shin slanted, and the mesh's ankles
    traced at its ankle's height come out too low and its knees bent (on the dash: SMPL's legs 12-15 cm from the
    mesh's middle instead of 3-8, CesiumMan's lower legs outside it); a rest bent at the spine stands its legs
    straight, which standing the trunk up turns with the pelvis."""
    def standing(limb) -> float:
        return float(-_unit(limb.end - limb.middle)[2])
    return {k: (replace(limb, tip_rise=upright[k].tip_rise)
                if k[1] == "leg" and standing(upright[k]) > standing(limb) else limb) for k, limb in rest.items()}


def turn_limbs(skeleton, q0: np.ndarray, limbs: dict, targets: dict) -> np.ndarray:
    """``q0`` with the joints of each limb's upper and lower bone set (least squares) so that the bones point along
    ``targets`` ((side, kind) -> (upper direction, lower direction[, hand / foot direction]), skeleton world frame),
    then the hand's or foot's own joints so that it points along the third; the joints' change is weighted lightly
    (REGULARIZE), which keeps each bone's twist."""
    from scipy.optimize import least_squares
    owned = skeleton.bone_joints()
    revolute = skeleton.revolute_mask()
    q = np.asarray(q0, dtype=np.float64).copy()
    for key, limb in limbs.items():
        joints = [j for b in (limb.upper, limb.lower) for j in owned[b] if revolute[j]]
        if not joints:
            continue
        t_up, t_low = (_unit(np.asarray(t, dtype=np.float64)) for t in targets[key][:2])
        x0 = q[joints].copy()
        # the hand / foot (its own joints, solved after the limb): from the wrist / ankle towards the mesh's tip
        hand = limb.distal if len(targets[key]) > 2 and limb.distal >= 0 else -1
        t_hand = _unit(np.asarray(targets[key][2], dtype=np.float64)) if hand >= 0 else None

        def residual(xs: np.ndarray) -> np.ndarray:
            qq = q.copy()
            qq[joints] = xs
            s, e = skeleton.bone_segments(qq)
            du, dl = _unit(e[limb.upper] - s[limb.upper]), _unit(e[limb.lower] - s[limb.lower])
            return np.concatenate([du - t_up, dl - t_low, REGULARIZE * (xs - x0)])

        q[joints] = least_squares(residual, x0, diff_step=1e-6, max_nfev=200 * len(joints)).x
        own = [j for j in owned[hand] if revolute[j]] if hand >= 0 else []
        if own:
            h0 = q[own].copy()

            def hand_residual(xs: np.ndarray) -> np.ndarray:
                qq = q.copy()
                qq[own] = xs
                s, e = skeleton.bone_segments(qq)
                return np.concatenate([_unit(e[hand] - s[hand]) - t_hand, REGULARIZE * (xs - h0)])

            q[own] = least_squares(hand_residual, h0, diff_step=1e-6, max_nfev=200 * len(own)).x
    return q


def _segment_points_distance(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    from .binding import segment_distance
    if len(polyline) < 2:
        return np.linalg.norm(points - polyline[0], axis=1)
    return segment_distance(points, polyline[:-1], polyline[1:]).min(axis=1)


def limb_report(pose: MeshPose, fit_apply, limbs: dict, starts: np.ndarray, ends: np.ndarray) -> tuple[str, dict]:
    """(one line, {(side, kind): (mean, max) [m]}): how far points along each limb's lower bone and the part of its
    upper bone the rings trace (from the elbow / knee up to UPPER_SPAN[1] of it; above, the rings run into the
    trunk) lie from the middle of the mesh's limb (its ring centroids carried by ``fit_apply``, the mesh's
    placement)."""
    w = np.linspace(0.0, 1.0, 6)[:, None]
    w_up = 1.0 - UPPER_SPAN[1] * w
    out, parts = {}, []
    for key in LIMBS:
        limb = limbs[key]
        middle = fit_apply(pose.limbs[key].middle)
        pts = np.vstack([starts[limb.upper] * (1 - w_up) + ends[limb.upper] * w_up,
                         starts[limb.lower] * (1 - w) + ends[limb.lower] * w])
        d = _segment_points_distance(pts, middle)
        out[key] = (float(d.mean()), float(d.max()))
        parts.append(f"{LIMB_NAMES[key]} {100 * d.mean():.1f} / {100 * d.max():.1f} cm")
    return "bones from the middle of the mesh's limbs (mean / max): " + ", ".join(parts), out


def bones_to_unbind(roles, outside: dict[str, float], margin: float = UNBIND_MARGIN,
                    parent: np.ndarray | None = None, ends: np.ndarray | None = None) -> list[str]:
    """The finger, toe and root-helper bones (by their role in the tree, UNBINDABLE_ROLES) with a point more than
    ``margin`` outside the skin (``outside``: bone -> how far its farthest point lies outside [m], <= 0 inside),
    and with ``parent`` and ``ends`` (the bind pose's bone ends) the head's parts (``head_parts``)."""
    names = roles.names
    chosen = {n for n in names if roles.roles[names.index(n)] in UNBINDABLE_ROLES and outside.get(n, 0.0) > margin}
    if parent is not None and ends is not None:
        chosen.update(names[b] for b in head_parts(roles, parent, ends))
    return [n for n in names if n in chosen]


def head_parts(roles, parent: np.ndarray, ends: np.ndarray) -> list[int]:
    """Bones of the neck and head that branch off the chain from the neck to the head's highest end (along
    roles.up): eyes, a jaw. Inside the head a few centimetres long, they would take the flesh nearest them, up to
    18 cm away (mesh2motion's head on the Mixamo rig's eyes), and carry it with their own turns against the head's;
    unbound, that flesh follows the head."""
    head = [b for b, r in enumerate(roles.roles) if r in ("neck", "head")]
    if not head:
        return []
    top = max(head, key=lambda b: float(ends[b] @ roles.up))
    chain, b = set(), top
    while b >= 0:
        chain.add(b)
        b = int(parent[b])
    return [b for b in head if b not in chain]


@dataclass
class AutoBind:
    q: np.ndarray               # (nq,) the bind configuration
    fit: object                 # fit.Fit of the mesh on the skeleton at q
    pose: MeshPose              # the mesh's pose, in the coordinates of ``first_fit``
    first_fit: object           # fit.Fit the mesh's pose was measured in
    roles: object               # bone_roles.BoneRoles of the skeleton at q
    limbs: dict                 # (side, kind) -> SkeletonLimb at q
    report: str                 # limb_report's line
    distances: dict             # limb_report's numbers


def auto_bind_pose(skeleton, q_rest: np.ndarray, vertices: np.ndarray, triangles: np.ndarray, unit: float,
                   up: str, forward: str, say=None) -> AutoBind:
    """The bind pose of ``skeleton`` in the mesh (``vertices`` in file units, ``triangles`` its closed surface) and
    the mesh's fit on it: the skeleton in ``q_rest`` with each limb turned onto the mesh's (module docstring), the
    mesh then placed (scale and offset, least squares) with its elbows, wrists, knees and ankles nearest the
    skeleton's, and moved (fit.refine_fit) so that the bones that bind (not the fingers, toes, root helpers) lie
    under its skin."""
    from ..skeleton.bone_roles import NotHumanoid, label_bones
    from .fit import fit_mesh, refine_fit
    say = say or (lambda _: None)
    starts, ends = skeleton.bone_segments(q_rest)
    try:
        roles = label_bones(skeleton.bone_names, skeleton.bone_parent, starts, ends)
    except NotHumanoid as exc:
        raise FitError(f"skeleton.bind_pose 'auto' finds the bind pose of a human skeleton, and this one is not "
                       f"({exc}): set skeleton.bind_pose 'neutral' or 'first_frame'") from None
    limbs = skeleton_limbs(roles, starts, ends)
    q, before = q_rest, trunk_lean(skeleton, q_rest, roles)
    if before[0] > TRUNK_LEAN:
        q = straighten_trunk(skeleton, q_rest, roles)
        after = trunk_lean(skeleton, q, roles)
        say(f"the skeleton's trunk leans {before[0]:.0f} deg from the vertical in its rest (its neck and head "
            f"{before[1]:.0f} deg): stood up as the mesh stands ({after[0]:.0f} / {after[1]:.0f} deg) before its limbs "
            "are turned onto the mesh's")
        limbs = _standing_feet(limbs, skeleton_limbs(roles, *skeleton.bone_segments(q)))
    first = fit_mesh(vertices, starts, ends, "auto", unit, up, forward)
    first, why = _trace_size(first, vertices, starts, ends, limbs)
    if why:
        say(why)
    pose = mesh_pose(first.apply(vertices), triangles, limbs, declared_forward=np.array([1.0, 0.0, 0.0]))
    say(pose.describe())
    for note in pose.notes:
        say(note)
    A = facing_rotation(pose, roles)
    targets = {k: (A @ pose.limbs[k].upper_dir, A @ pose.limbs[k].lower_dir,
                   A @ (pose.limbs[k].tip - pose.limbs[k].end)) for k in LIMBS}
    q = turn_limbs(skeleton, q, limbs, targets)
    R = A @ first.rotation
    marks = np.vstack([first.inverse(np.array([pose.limbs[k].middle_joint, pose.limbs[k].end])) for k in LIMBS])
    # the clavicles and hip bones keep the rest's angles: the capture plays its own on them, and a girdle turned
    # at bind time would move the shoulder or hip joint under the flesh by as much on every frame
    starts, ends = skeleton.bone_segments(q)
    limbs = skeleton_limbs(roles, starts, ends)          # the roles of the rest pose, the joints where q puts them
    fit = _landmark_fit(R, first.scale, marks, np.vstack([[limbs[k].middle, limbs[k].end] for k in LIMBS]))
    # then moved (not scaled: a larger mesh swallows every bone) until the bones that bind lie under the skin
    binds = np.array([r not in UNBINDABLE_ROLES for r in roles.roles])
    fit = refine_fit(fit, vertices, triangles, starts[binds], ends[binds], scale=False)
    report, distances = limb_report(pose, lambda pts: fit.apply(first.inverse(pts)), limbs, starts, ends)
    return AutoBind(q, fit, pose, first, roles, limbs, report, distances)


def _trace_size(first, vertices: np.ndarray, starts: np.ndarray, ends: np.ndarray, limbs: dict):
    """(fit, the line saying what was decided or ''): ``first`` (the mesh sized so the skeleton spans
    fit.HEIGHT_RATIO of it) made larger when the skeleton's hips stand higher than HIP_RATIO of that size: the
    limbs are traced at the skeleton's lengths from the mesh's tips, and a mesh too small for its skeleton's legs
    has their upper rings run on into the trunk (their centre then lies towards the middle: the thighs are turned
    inwards). A head end site short of the crown (Bandai Namco's rig ends 10 cm above the head joint) makes a
    skeleton look shorter than it is; the hips do not depend on it. The landmark fit then sizes the mesh."""
    from .fit import Fit
    x = first.apply(vertices)
    height = float(np.ptp(x[:, 2]))
    soles = float(np.vstack([starts, ends])[:, 2].min())
    hips = float(np.mean([limbs[(side, "leg")].root[2] for side in "lr"])) - soles
    k = hips / (HIP_RATIO * height)
    if k <= 1.0:
        return first, ""
    centre = 0.5 * (x.min(axis=0) + x.max(axis=0))
    grown = Fit(first.rotation, first.scale * k, centre - k * (centre - first.offset))
    return grown, (f"the skeleton's hips stand {hips / height:.3f} of the mesh's height "
                   f"above its soles, a human's {HIP_RATIO:g}: its limbs are traced on the mesh made {k:.3f} times "
                   "larger (a head end site short of the crown makes the skeleton look short)")


def _landmark_fit(R: np.ndarray, scale0: float, marks: np.ndarray, joints: np.ndarray):
    """fit.Fit with rotation ``R`` whose scale and offset put the mesh's landmarks ``marks`` (file units) nearest
    the skeleton's ``joints`` (least squares); FitError when the scale is far from ``scale0`` (the height's)."""
    from .fit import Fit
    y = marks @ R.T
    yc, jc = y - y.mean(axis=0), joints - joints.mean(axis=0)
    scale = float(np.sum(yc * jc) / np.sum(yc * yc))
    if not 0.5 * scale0 <= scale <= 2.0 * scale0:
        raise FitError(f"the mesh's elbows, wrists, knees and ankles fit the skeleton's at {scale / scale0:.2f} "
                       "times the size its height gives: the mesh's limbs are not where a human's are; check "
                       "skeleton.fit_up and body.surface_unit")
    return Fit(R, scale, joints.mean(axis=0) - scale * y.mean(axis=0))


def rest_configuration(skeleton, bvh_file: str = "", bvh_unit="auto", bvh_up: str = "auto") -> tuple[np.ndarray, str]:
    """(q, the line saying which): the skeleton's rest the limbs are turned from: its zero pose when a human stands in
    it (bone_roles: feet to head within 45 deg of up), else frame 0 of ``bvh_file`` (the capture played) when one
    stands there; FitError naming the way out otherwise."""
    from ..skeleton.bone_roles import stands_in
    from .fit import bind_configuration

    zero, zero_why = stands_in(skeleton)
    if zero:
        return skeleton.neutral(), f"bind pose from the skeleton's zero pose ({zero_why})"
    if not bvh_file:
        raise FitError(f"no human stands in the skeleton's zero pose ({zero_why}) and skeleton.bind_bvh names no "
                       "capture whose frame 0 could serve: play the capture with --bvh (the scene then binds on its "
                       "frame 0) or set skeleton.bind_bvh")
    q = bind_configuration(skeleton, "first_frame", bvh_file=bvh_file, bvh_unit=bvh_unit, bvh_up=bvh_up)
    first, first_why = stands_in(skeleton, q)
    if not first:
        raise FitError(f"no human stands in the skeleton's zero pose ({zero_why}) nor in frame 0 of "
                       f"{bvh_file} ({first_why}): check the capture's up axis (the player's 'up', skeleton.bvh_up)")
    return q, f"bind pose from frame 0 of {bvh_file}: no human stands in the zero pose ({zero_why}), one does there"
