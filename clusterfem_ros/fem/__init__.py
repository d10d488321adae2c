"""The numerical core, no ROS: tetrahedral meshes, linear elasticity, the clustered force kernels, the materials
and the time integrators, in sub-packages that import one way, from the bottom up:

- ``mesh/``: tet meshes, their checks and quality, voxel meshes, meshing surfaces, mesh files;
- ``linear/``: the linear elastic material and the element stiffness, assembly and lumped mass;
- ``kernels/``: the clusters of K (the paper's eqs. 5-6), their SIMD slices and the compiled cluster passes;
- ``model.py`` and ``stability.py``: the fixed model, state and control every method shares, and the explicit
  step's stability limit;
- ``materials/``: what an element's force is: corotated warping (per element, per vertex), stable Neo-Hookean,
  polar decomposition, the stretch plan, stress;
- ``integrators/``: the clustered explicit method and the reference methods behind one ``step``.

tests/test_layering.py holds these layers to their order.
"""
