"""Explicit dynamics of the linear elastic Cosserat continuum (003 section 2.3, eqs 31-34):
lumped mass (mass.py), stable time step (stable_step.py), velocity Verlet with mass damping
(explicit.py). The quasi-static Newton path (problem.py, snes.py) does not use this package."""
from .explicit import DynamicsError, ExplicitCosserat
from .stable_step import rotational_step, translational_step

__all__ = ["DynamicsError", "ExplicitCosserat", "rotational_step", "translational_step"]
