"""What an element's elastic force is, beyond the linear one: per-element corotation (element_warping.py, its
rotations in element_rotation.py, the assembled reference in corotational.py and assembled_warp.py), the paper's
per-vertex warping (warping.py), stable Neo-Hookean elements (neohookean.py, the default), the polar decomposition
they share (polar.py), the models by name (warping_models.py), how far stretching stiffens a body and shortens the
step (stretch.py), the stress of a state (stress.py), and the argument checks of the force entries
(kernel_args.py)."""
