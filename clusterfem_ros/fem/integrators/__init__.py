"""Time integrators behind one interface: ``step(state, control, h) -> StepInfo``.

Every method holds a fixed ``FemModel`` and advances a ``State`` in place, so benchmarks and the node
can swap them freely (see ``make_integrator``, factory.py). The methods: clustered_explicit.py (the paper's),
standard_explicit.py, standard_implicit.py and modal.py (its basis keeps every rigid mode: rigid_modes.py);
base.py holds what they share, spd_factor.py the sparse direct solves of the implicit and modal methods.
"""
from .base import Integrator, StepInfo  # noqa: F401
from .factory import make_integrator  # noqa: F401
