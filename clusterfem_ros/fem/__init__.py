"""The numerical core: meshes, linear elasticity, the clustered force kernel, integrators."""
