"""Isotropic linear elastic material with Rayleigh damping, validated once at the edge."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...errors import ClusterFemError


# The one set of default material values: Material()'s and the scene's (config.py reads these). E = 30 kPa,
# nu = 0.3, rho = 1000 kg/m^3: a soft jelly of water's density, the paper's test material.
DEFAULT_YOUNG_MODULUS = 3.0e4
DEFAULT_POISSON_RATIO = 0.3
DEFAULT_DENSITY = 1000.0
# Rayleigh damping:
# zeta = 1e-4 s, not 1e-5: a joint-state stall of ~80 ms and the burst after it made the warped jelly man's one-
# and two-tet flaps (free vertices on the shins) flutter and diverge within a second at 1e-5. 1e-4 damps the
# mesh's highest modes (damping ratio ~0.04 at ~800 rad/s) and leaves the body's own (< 0.003 below 50 rad/s);
# 1e-3 damped those highest modes critically and cut the explicit critical step. xi = 2 / s settles the body's
# slow modes in about a second. The stability table runs every hard case undamped and at these values
# (benchmarks/stability_table.py).
DEFAULT_MASS_DAMPING = 2.0
DEFAULT_STIFFNESS_DAMPING = 1.0e-4


class ParameterError(ClusterFemError, ValueError):
    """A physical parameter out of its valid range; the message names the value and the range."""


@dataclass(frozen=True)
class Material:
    """Young's modulus ``E`` [Pa], Poisson ratio ``nu`` [-], density ``rho`` [kg/m^3].

    Rayleigh damping D = xi * M + zeta * K: ``xi`` [1/s] damps low frequencies, ``zeta`` [s] high ones.
    """
    E: float = DEFAULT_YOUNG_MODULUS
    nu: float = DEFAULT_POISSON_RATIO
    rho: float = DEFAULT_DENSITY
    xi: float = DEFAULT_MASS_DAMPING
    zeta: float = DEFAULT_STIFFNESS_DAMPING

    def __post_init__(self) -> None:
        check = [("E", self.E, 0.0, np.inf, "Pa"), ("nu", self.nu, -1.0, 0.5, "-"),
                 ("rho", self.rho, 0.0, np.inf, "kg/m^3")]
        for name, value, lo, hi, unit in check:
            if not (np.isfinite(value) and lo < value < hi):
                raise ParameterError(f"material {name} = {value!r} {unit} is outside ({lo}, {hi}): "
                                     f"give a finite value inside the range")
        for name, value in (("xi", self.xi), ("zeta", self.zeta)):
            if not (np.isfinite(value) and value >= 0):
                raise ParameterError(f"Rayleigh damping {name} = {value!r} must be finite and >= 0")

    @property
    def lame(self) -> tuple[float, float]:
        """(lambda, mu) Lamé parameters [Pa]."""
        mu = self.E / (2.0 * (1.0 + self.nu))
        lam = self.E * self.nu / ((1.0 + self.nu) * (1.0 - 2.0 * self.nu))
        return lam, mu

    def elasticity_matrix(self) -> np.ndarray:
        """6x6 Voigt matrix C (strain order xx, yy, zz, yz, xz, xy with engineering shear strains)."""
        lam, mu = self.lame
        C = np.zeros((6, 6))
        C[:3, :3] = lam
        C[np.arange(3), np.arange(3)] += 2.0 * mu
        C[np.arange(3, 6), np.arange(3, 6)] = mu
        return C
