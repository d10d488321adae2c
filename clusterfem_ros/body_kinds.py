"""The kinds of body a scene may build (``body.kind``), declared: each a ``BodyDeclaration`` with the flags the
scene configuration checks (config.py takes its choices and cross-checks from these, building nothing) and where
its builder is, loaded when a scene first builds one (scene_build.body_kind). No numba, no meshing here.

A new body kind is one module holding its builder (``build(config, skeleton, urdf_xml, leaf_shapes, progress) ->
scene_build.SceneParts``) and one ``declare_body_kind`` call.
"""
from __future__ import annotations

from dataclasses import dataclass

from .registries import Registry


@dataclass(frozen=True)
class BodyDeclaration:
    name: str
    builder: str                    # 'package.module:function' that builds its SceneParts
    file_param: str = ""            # the scene parameter naming the file it is built from ('' = none)
    file_what: str = ""             # what that file holds, for the refusal ('the path of a volume mesh')
    needs_skeleton: bool = False    # built around (or bound to) a skeleton: refused with skeleton.source 'none'
    leaf_shapes: bool = False       # the skeleton's URDF is prepared with its leaf links' shapes as flesh
    flesh_depth: bool = False       # it knows each vertex's depth under the skin (binding.relative_levels)
    volume_stiffness: float = 0.0   # material.volume_stiffness 'auto' runs this whole-volume pressure (0 = none)


BODY_DECLARATIONS = Registry("body kind")


def declare_body_kind(declaration: BodyDeclaration) -> BodyDeclaration:
    """Make ``declaration.name`` a scene's choice of body.kind (a name already taken is refused); returns it."""
    return BODY_DECLARATIONS.register(declaration.name, declaration)


_BUILD = "clusterfem_ros.scene_build"
# Flesh on a skeleton (the jelly man, a character's surface) keeps its volume where bent joints crush it: the
# whole volume's pressure at kappa 2 on 'auto' (docs/method.md, Constraints); the paper's shapes, volume meshes and
# robot covers run the elements alone, as the paper does.
FLESH_PRESSURE = 2.0
for _d in (BodyDeclaration("jelly_man", f"{_BUILD}:build_jelly_man", needs_skeleton=True, leaf_shapes=True,
                           volume_stiffness=FLESH_PRESSURE),
           BodyDeclaration("sphere", f"{_BUILD}:build_paper_shape"),
           BodyDeclaration("cube", f"{_BUILD}:build_paper_shape"),
           BodyDeclaration("torus", f"{_BUILD}:build_paper_shape"),
           BodyDeclaration("mesh", f"{_BUILD}:build_volume_mesh", "body.mesh_file", "the path of a volume mesh"),
           BodyDeclaration("surface", f"{_BUILD}:build_surface", "body.surface_file",
                           "the path of a triangle surface mesh", needs_skeleton=True, flesh_depth=True,
                           volume_stiffness=FLESH_PRESSURE),
           BodyDeclaration("robot_cover", f"{_BUILD}:build_robot_cover", needs_skeleton=True)):
    declare_body_kind(_d)
BODY_DECLARATIONS.seal()
BODIES = BODY_DECLARATIONS.names()          # what a scene may choose (a live view)

