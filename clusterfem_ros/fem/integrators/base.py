"""The shared integrator interface and the pieces every method uses."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from ..model import Control, FemModel, State
from ..materials.material_model import MaterialModel
from ..stability import check_finite


@dataclass(frozen=True)
class StepInfo:
    substeps: int = 1
    margin: float = float("inf")    # h_crit / h_sub for explicit methods; inf for unconditionally stable ones
    iterations: int = 0             # linear-solver iterations (CG)


class Integrator(Protocol):
    name: str
    model: FemModel
    material_model: MaterialModel       # what its elastic force is (fem/materials/material_model.py)

    def step(self, state: State, control: Control, h: float) -> StepInfo: ...


class StepCommon:
    """What every method precomputes once from the model: gravity, fixed indices, the divergence limit."""

    def __init__(self, model: FemModel):
        self.model = model
        self.gravity_force = model.gravity_force()
        self.fixed_index = np.flatnonzero(model.fixed)
        # A displacement no sane simulation of this body reaches: 100 body diagonals plus 1 km of travel.
        self.limit = 100.0 * float(np.ptp(model.rest, axis=0).max()) + 1000.0

    def constant_forces(self, control: Control) -> np.ndarray:
        """Gravity plus the control's external forces, (n, 3)."""
        if control.f_ext is None:
            return self.gravity_force
        if control.f_ext.shape != self.gravity_force.shape:
            raise ValueError(f"f_ext has shape {control.f_ext.shape}, expected {self.gravity_force.shape}")
        return self.gravity_force + control.f_ext

    def apply_prescribed(self, state: State, control: Control) -> np.ndarray | None:
        """Hold fixed vertices at rest and set prescribed ones from the control.

        Returns the (n,) mask of vertices not integrated (fixed or prescribed), or None when that is
        just the model's fixed set.
        """
        if self.fixed_index.size:
            state.u[self.fixed_index] = 0.0
            state.v[self.fixed_index] = 0.0
        idx = control.prescribed_index
        if not idx.size:
            return None
        state.u[idx] = control.prescribed_u
        state.v[idx] = control.prescribed_v
        held = self.model.fixed.copy()
        held[idx] = True
        return held

    def finish(self, state: State, h: float, name: str, checked: bool = False) -> None:
        """Advance time and raise DivergenceError on a non-finite or exploding state.

        ``checked``: the kernel already found every |u| within ``limit`` and nothing non-finite, so the
        state is not scanned again (a False from such a kernel leads to the scan, which names the problem).
        """
        state.t += h
        if not checked:
            check_finite(state.u, state.v, self.limit, where=f"in {name} at t = {state.t:.6g} s")
