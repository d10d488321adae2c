"""Stress of a displacement field: per element, per vertex, von Mises and principal values [Pa].

Per tet (constant strain): F = I + grad u, R_e = polar(F) when ``corotated`` (stiffness warping) and
R_e = I for the linear model, small strain eps = sym(R_e^T F - I), stress in the element's rest frame
s = C eps = lambda tr(eps) I + 2 mu eps, returned in the world frame sigma = R_e s R_e^T (the Cauchy
stress of the corotated linear model; invariants such as von Mises do not depend on the frame).
von Mises = sqrt(3/2 dev(sigma) : dev(sigma)); principal stresses = eigvalsh(sigma), ascending.
Per vertex: the volume-weighted average of the adjacent elements' tensors, and its invariants.
"""
from __future__ import annotations

import weakref
from dataclasses import dataclass

import numba
import numpy as np

from .assembly import shape_gradients
from .model import FemModel
from .numba_config import SERIAL
from .warping import _rotation_of


@dataclass(frozen=True)
class StressField:
    element_stress: np.ndarray          # (m, 3, 3) Cauchy stress [Pa]
    element_von_mises: np.ndarray       # (m,)
    vertex_stress: np.ndarray           # (n, 3, 3) volume-weighted average of adjacent elements
    vertex_von_mises: np.ndarray        # (n,)

    @property
    def element_principal(self) -> np.ndarray:
        """(m, 3) principal stresses, ascending (computed on access: an eigen-solve per element)."""
        return np.linalg.eigvalsh(self.element_stress)

    @property
    def vertex_principal(self) -> np.ndarray:
        """(n, 3) principal stresses of the vertex tensors, ascending (computed on access)."""
        return np.linalg.eigvalsh(self.vertex_stress)


def von_mises(sigma, u: np.ndarray | None = None, corotated: bool = True) -> np.ndarray:
    """sqrt(3/2 s:s), s = dev(sigma), for a stack of tensors (..., 3, 3).

    Also ``von_mises(model, u)``: the per-element von Mises stress of displacement u (corotated by
    default: equal to the linear value for small deformations, and free of the linear model's spurious
    stress under large rotation; pass corotated=False for the linear one).
    """
    if isinstance(sigma, FemModel):
        return compute_stress(sigma, u, corotated=corotated).element_von_mises
    return von_mises_of(np.asarray(sigma, dtype=np.float64))


def element_von_mises(model: FemModel, u: np.ndarray, corotated: bool = True) -> np.ndarray:
    """Per-element von Mises stress (m,) [Pa] of displacement u."""
    return compute_stress(model, u, corotated=corotated).element_von_mises


def von_mises_of(sigma: np.ndarray) -> np.ndarray:
    """sqrt(3/2 s:s), s = dev(sigma), for a stack (..., 3, 3)."""
    tr = np.trace(sigma, axis1=-2, axis2=-1)
    s = sigma - tr[..., None, None] / 3.0 * np.eye(3)
    return np.sqrt(1.5 * np.einsum("...ij,...ij->...", s, s))


# gradients of each model's rest mesh, kept while the model lives (the node asks at 10 Hz)
_GRADIENTS: dict[int, tuple[weakref.ref, np.ndarray, np.ndarray, np.ndarray]] = {}


def _rest_data(model: FemModel):
    hit = _GRADIENTS.get(id(model))
    if hit is not None and hit[0]() is model:
        return hit[1:]
    g, vol = shape_gradients(model.rest, model.mesh.tets)
    w = np.bincount(model.mesh.tets.ravel(), weights=np.repeat(vol, 4), minlength=model.n_vertices)
    _GRADIENTS[id(model)] = (weakref.ref(model, lambda _, k=id(model): _GRADIENTS.pop(k, None)), g, vol, w)
    return g, vol, w


@numba.njit(**SERIAL)
def _element_stress(g, tets, u, lam, mu, corotated, sigma):
    """sigma[e] <- world-frame Cauchy stress of tet e (see the module docstring); one pass, no temporaries."""
    F = np.empty((3, 3))
    X = np.empty((3, 3))
    R = np.empty((3, 3))
    G = np.empty((3, 3))
    s = np.empty((3, 3))
    for e in range(tets.shape[0]):
        for a in range(3):
            for b in range(3):
                acc = 1.0 if a == b else 0.0
                for c in range(4):
                    acc += u[tets[e, c], a] * g[e, c, b]
                F[a, b] = acc
        if corotated:
            for a in range(3):
                for b in range(3):
                    R[a, b] = 1.0 if a == b else 0.0      # start of the fallback for inverted tets
            _rotation_of(F, X, R)
            for a in range(3):
                for b in range(3):
                    G[a, b] = R[0, a] * F[0, b] + R[1, a] * F[1, b] + R[2, a] * F[2, b]   # R^T F
        else:
            for a in range(3):
                for b in range(3):
                    G[a, b] = F[a, b]
        tr = G[0, 0] + G[1, 1] + G[2, 2] - 3.0
        for a in range(3):
            for b in range(3):
                s[a, b] = mu * (G[a, b] + G[b, a]) + ((lam * tr - 2.0 * mu) if a == b else 0.0)
        if corotated:                                     # sigma = R s R^T
            for a in range(3):
                for b in range(3):
                    acc = 0.0
                    for c in range(3):
                        for d in range(3):
                            acc += R[a, c] * s[c, d] * R[b, d]
                    sigma[e, a, b] = acc
        else:
            for a in range(3):
                for b in range(3):
                    sigma[e, a, b] = s[a, b]


def compute_stress(model: FemModel, u: np.ndarray, corotated: bool = False) -> StressField:
    """Element and vertex stress of displacement ``u`` (n, 3); ``corotated`` for the warped model."""
    u = np.asarray(u, dtype=np.float64)
    if u.shape != (model.n_vertices, 3):
        raise ValueError(f"u has shape {u.shape}, expected ({model.n_vertices}, 3) for this mesh")
    if not np.isfinite(u).all():
        raise ValueError("u has non-finite entries: the state diverged, stress is undefined; reset the state")
    g, vol, w = _rest_data(model)
    tets = model.mesh.tets
    lam, mu = model.material.lame
    sigma = np.empty((tets.shape[0], 3, 3))
    _element_stress(g, tets, u, float(lam), float(mu), bool(corotated), sigma)
    weighted = (vol[:, None, None] * sigma).reshape(-1, 9)
    corners = tets.ravel()
    vs = np.stack([np.bincount(corners, weights=np.repeat(weighted[:, c], 4), minlength=model.n_vertices)
                   for c in range(9)], axis=1).reshape(-1, 3, 3)
    vs /= w[:, None, None]
    return StressField(sigma, von_mises_of(sigma), vs, von_mises_of(vs))
