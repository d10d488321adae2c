"""Forward kinematics of a tree of scalar joints as a numba kernel (the hot path of ``Skeleton.forward``).

Pinocchio computes the same placements (``Skeleton.forward_pinocchio`` is the reference the tests
compare against), but reading ~30 placements and twists back into numpy through its Python bindings
costs ~100 us per call; this kernel computes them in ~1 us from pinocchio's constant model data.

Per joint i (parents before children): oR_i = oR_par Rpl_i Rot(a_i, q_i) for a revolute joint,
op_i = op_par + oR_par (ppl_i + Rpl_i a_i q_i [prismatic]); world-aligned spatial velocity at the joint
origin: w_i = w_par + oR_par Rpl_i a_i qd_i [revolute], v_i = v_par + w_par x (op_i - op_par)
+ oR_par Rpl_i a_i qd_i [prismatic]. A frame f on joint j at (fR, fp): R = oR_j fR, p = op_j + oR_j fp,
twist = (w_j, v_j + w_j x (p - op_j)).
"""
from __future__ import annotations

import numba
import numpy as np

from ..numba_config import HOLDS_GIL


@numba.njit(**HOLDS_GIL)
def _axis_rotation(a0, a1, a2, angle, out):
    c, s = np.cos(angle), np.sin(angle)
    t = 1.0 - c
    out[0, 0], out[0, 1], out[0, 2] = c + a0 * a0 * t, a0 * a1 * t - a2 * s, a0 * a2 * t + a1 * s
    out[1, 0], out[1, 1], out[1, 2] = a1 * a0 * t + a2 * s, c + a1 * a1 * t, a1 * a2 * t - a0 * s
    out[2, 0], out[2, 1], out[2, 2] = a2 * a0 * t - a1 * s, a2 * a1 * t + a0 * s, c + a2 * a2 * t


@numba.njit(**HOLDS_GIL)
def tree_forward(parent, place_R, place_p, axis, prismatic, q, qd, frame_joint, frame_R, frame_p,
                 oR, op, w, vo, R_out, p_out, tw_out):
    """Fill R_out (nb, 3, 3), p_out (nb, 3), tw_out (nb, 6); oR, op, w, vo are (nj, ...) scratch. Returns False,
    filling nothing, if a value of q or qd is not finite."""
    for k in range(q.shape[0]):
        if not np.isfinite(q[k]):
            return False
    for k in range(qd.shape[0]):
        if not np.isfinite(qd[k]):
            return False
    rot = np.empty((3, 3))
    base = np.empty((3, 3))
    for i in range(parent.shape[0]):
        par = parent[i]
        # base = oR_par @ Rpl_i ; origin = op_par + oR_par @ ppl_i
        for r in range(3):
            for c in range(3):
                acc = 0.0
                for k in range(3):
                    acc += (oR[par, r, k] if par >= 0 else (1.0 if r == k else 0.0)) * place_R[i, k, c]
                base[r, c] = acc
        # world axis oR_par Rpl a, as scalars (not an array allocated per joint)
        wa0 = base[0, 0] * axis[i, 0] + base[0, 1] * axis[i, 1] + base[0, 2] * axis[i, 2]
        wa1 = base[1, 0] * axis[i, 0] + base[1, 1] * axis[i, 1] + base[1, 2] * axis[i, 2]
        wa2 = base[2, 0] * axis[i, 0] + base[2, 1] * axis[i, 1] + base[2, 2] * axis[i, 2]
        for r in range(3):
            acc = 0.0
            for k in range(3):
                acc += (oR[par, r, k] if par >= 0 else (1.0 if r == k else 0.0)) * place_p[i, k]
            op[i, r] = (op[par, r] if par >= 0 else 0.0) + acc
        if prismatic[i]:
            op[i, 0] += wa0 * q[i]
            op[i, 1] += wa1 * q[i]
            op[i, 2] += wa2 * q[i]
            for r in range(3):
                for c in range(3):
                    oR[i, r, c] = base[r, c]
        else:
            _axis_rotation(axis[i, 0], axis[i, 1], axis[i, 2], q[i], rot)
            for r in range(3):
                for c in range(3):
                    oR[i, r, c] = base[r, 0] * rot[0, c] + base[r, 1] * rot[1, c] + base[r, 2] * rot[2, c]
        if par >= 0:
            d0, d1, d2 = op[i, 0] - op[par, 0], op[i, 1] - op[par, 1], op[i, 2] - op[par, 2]
            w0, w1, w2 = w[par, 0], w[par, 1], w[par, 2]
            w[i, 0], w[i, 1], w[i, 2] = w0, w1, w2
            vo[i, 0] = vo[par, 0] + w1 * d2 - w2 * d1
            vo[i, 1] = vo[par, 1] + w2 * d0 - w0 * d2
            vo[i, 2] = vo[par, 2] + w0 * d1 - w1 * d0
        else:
            for r in range(3):
                w[i, r] = 0.0
                vo[i, r] = 0.0
        if prismatic[i]:
            vo[i, 0] += wa0 * qd[i]
            vo[i, 1] += wa1 * qd[i]
            vo[i, 2] += wa2 * qd[i]
        else:
            w[i, 0] += wa0 * qd[i]
            w[i, 1] += wa1 * qd[i]
            w[i, 2] += wa2 * qd[i]
    for b in range(frame_joint.shape[0]):
        j = frame_joint[b]
        for r in range(3):
            for c in range(3):
                if j >= 0:
                    R_out[b, r, c] = oR[j, r, 0] * frame_R[b, 0, c] + oR[j, r, 1] * frame_R[b, 1, c] \
                        + oR[j, r, 2] * frame_R[b, 2, c]
                else:
                    R_out[b, r, c] = frame_R[b, r, c]
        for r in range(3):
            if j >= 0:
                p_out[b, r] = op[j, r] + oR[j, r, 0] * frame_p[b, 0] + oR[j, r, 1] * frame_p[b, 1] \
                    + oR[j, r, 2] * frame_p[b, 2]
            else:
                p_out[b, r] = frame_p[b, r]
        if j >= 0:
            d0, d1, d2 = p_out[b, 0] - op[j, 0], p_out[b, 1] - op[j, 1], p_out[b, 2] - op[j, 2]
            w0, w1, w2 = w[j, 0], w[j, 1], w[j, 2]
            tw_out[b, 0], tw_out[b, 1], tw_out[b, 2] = w0, w1, w2
            tw_out[b, 3] = vo[j, 0] + w1 * d2 - w2 * d1
            tw_out[b, 4] = vo[j, 1] + w2 * d0 - w0 * d2
            tw_out[b, 5] = vo[j, 2] + w0 * d1 - w1 * d0
        else:
            for r in range(6):
                tw_out[b, r] = 0.0
    return True
