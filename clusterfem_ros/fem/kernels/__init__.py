"""The clustered representation of K and the passes over it: each vertex's cluster of stiffness blocks
(clusters.py, the paper's eqs. 5-6), packed as SIMD slices of C rows (cluster_slices.py), the linear
elastic-damping force in one fused compiled pass (cluster_force_kernel.py), the warped force's passes
(warped_force_kernel.py), and the LLVM IR building blocks they are written in (llvm_ir.py)."""
