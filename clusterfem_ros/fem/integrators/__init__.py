"""Time integrators behind one interface: ``step(state, control, h) -> StepInfo``.

Every method holds a fixed ``FemModel`` and advances a ``State`` in place, so benchmarks and the node
can swap them freely (see ``make_integrator``).
"""
from .base import Integrator, StepInfo, make_integrator  # noqa: F401
