"""Material models, as the integrators ask them: the contract (material_model.py) and the models by name
(registry.py: linear, 'element', 'vertex', 'neohookean'); and what an element's elastic force is beyond the
linear one: per-element corotation (element_warping.py, its rotations in element_rotation.py, the assembled
references in corotational.py and assembled_warp.py), the paper's per-vertex warping (warping.py), stable
Neo-Hookean elements (neohookean.py, the default), the polar decomposition they share (polar.py), the names and
refusals a scene's configuration shares (warping_models.py), how far stretching stiffens a body and shortens the
step (stretch.py), the stress of a state (stress.py), and the argument checks of the force entries
(kernel_args.py)."""
