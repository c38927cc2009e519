"""The soft leg: one planar Cosserat rod with its loads, integrators and statics (numba kernels).

- :mod:`.rod`: geometry, elastic energy, forces and banded Hessian, the banded solver,
  and the paper's comparison model;
- :mod:`.loads`: tendon, gravity, tip load, ground contact and friction, the damping
  reaction on the root;
- :mod:`.integrators`: the symplectic and linearly implicit steps, the stability
  limit, and :class:`~.integrators.LegSim`;
- :mod:`.params`: the packed parameter and output arrays the kernels share;
- :mod:`.statics`: one leg clamped at its root, driven to equilibrium.

The coupled torso + four legs plant is :mod:`slotexp.plants.cosserat`.
"""
