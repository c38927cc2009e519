"""The soft legs: planar Cosserat rods with their loads, integrators and statics, and the torso they carry (numba).

- :mod:`.rod`: geometry, elastic energy, forces and banded Hessian, the banded solver,
  and the paper's comparison model;
- :mod:`.loads`: tendon, gravity, tip load, ground contact and friction, the damping
  reaction on the root;
- :mod:`.integrators`: the symplectic and linearly implicit steps, the stability
  limit, and :class:`~.integrators.LegSim`;
- :mod:`.params`: the packed parameter and output arrays the kernels share;
- :mod:`.statics`: one leg clamped at its root, driven to equilibrium;
- :mod:`.coupled`: the rigid torso and four legs stepped together, one robot or a batch.

The Plant around the coupled kernels is :mod:`slotexp.plants.cosserat`.
"""
