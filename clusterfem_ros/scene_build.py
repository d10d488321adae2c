"""What a scene is built from, chosen from its config: the error budget's method, the skeleton, the body's
mesh and fixed vertices, the material and the integrator's options. No ROS.

Building a scene goes: ``scene_parts`` (here) chooses and reads the parts, scene_setup.set_up wires them into
the parts that run (model, integrator, anchors, the body's binding to the skeleton, the joint inputs) and
scene_setup.warm_up loads their compiled kernels; scene.Scene runs them (inputs, clock, steps, checks, outputs). ``scene_parts`` reads the files a config
names (a URDF, a mesh, the error budget's measured points) and nothing else.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from .body.fit import bind_configuration, find_data_file
from .body.surface_body import SurfaceBody, build_surface_body
from .config import SceneConfig
from .fem.linear.material import Material
from .fem.mesh.mesh_io import read_mesh
from .fem.mesh.tet_mesh import TetMesh
from .fem.mesh.voxel_mesh import paper_mesh
from .method_choice import SHIPPED_POINTS, choose_from_file
from .body_kinds import BODY_DECLARATIONS, BodyDeclaration
from .registries import Registry, load_object
from .skeleton.bone_roles import NotHumanoid, flesh_radii, label_skeleton
from .skeleton.humanoid import HumanoidSpec, default_humanoid
from .skeleton.jelly_body import jelly_man_mesh, voxel_bones
from .skeleton.kinematics import Skeleton, UrdfError
from .skeleton.smooth_body import smooth_jelly_man_meshes
from .skeleton.link_shapes import prepare_urdf
from .skeleton.robot_cover import RobotCover, robot_cover
from .skeleton.urdf_check import UrdfLimits, UrdfRefused, check_urdf, read_urdf_file

MEASURED_POINTS = SHIPPED_POINTS
URDF_MANIFEST = "config/urdf_data.md"     # where skeleton.urdf_file data that is not in the repository comes from


def say(progress: Callable[[str], None] | None, text: str) -> None:
    """``progress(text)`` when a progress callback is given."""
    if progress is not None:
        progress(text)


@dataclass
class SceneParts:
    """What a scene is built from, chosen from a config (scene_parts); scene_setup.set_up wires it."""
    config: SceneConfig             # with the error budget's choice applied
    mesh: TetMesh
    fixed: np.ndarray               # (n,) bool: vertices held at rest
    skeleton: Skeleton | None       # None: skeleton.source = none
    urdf_xml: str | None
    surface: SurfaceBody | None = None   # of a surface body: its bind pose and depth under the skin
    bind_all: bool = False          # the outermost binding level reaches every vertex (a capsule body)
    cover: RobotCover | None = None     # of a robot cover: each vertex's link bone and depth
    bind_q: np.ndarray | None = None    # (nq,) the skeleton's configuration the jelly body was built in (None: q = 0)
    bare_bones: tuple[str, ...] = ()    # bones of a jelly body without flesh: they bind none (bone_roles.flesh_radii)
    vertex_bones: np.ndarray | None = None  # (n, nb) bool: the bones a vertex may bind to (a jelly body on a URDF)
    mass_reference: TetMesh | None = None   # the mesh of the same tets whose stiffest vertex (for its mass) no vertex
                                            # may exceed: the smooth jelly man's voxels (fem/mass_scaling.py)


def material_of(c: SceneConfig) -> Material:
    m = c.material
    return Material(E=m.young_modulus, nu=m.poisson_ratio, rho=m.density, xi=m.mass_damping, zeta=m.stiffness_damping)


def integrator_choice(config: SceneConfig) -> tuple[str, dict]:
    """(method, options) for fem.integrators.make_integrator, from the config's method, physics and warping."""
    method = config.method
    options: dict = {}
    if method in ("clustered", "standard_explicit"):
        options.update(safety=config.physics.safety, max_substeps=config.physics.max_substeps)
    if method == "modal":
        options["k"] = config.modal.k
    if config.warping and method != "modal":
        options["warp"] = True
        options["warping_model"] = config.warping_model
        options["allow_unbounded_warping"] = config.physics.allow_unbounded_warping
        if method in ("clustered", "standard_explicit"):
            options["plan_stretch"] = config.physics.plan_stretch
        if method.startswith("implicit"):
            options["max_substeps"] = config.physics.max_substeps
    return method, options


def apply_error_budget(config: SceneConfig, progress: Callable[[str], None] | None = None) -> SceneConfig:
    """The config with method, step, warping (and modal.k) replaced by the cheapest measured point that
    meets budget.max_error_mm; ChoiceError names the best achievable error when none does."""
    path = config.budget.measured_points or str(MEASURED_POINTS)
    choice = choose_from_file(path, scene=config.body.kind, budget_mm=config.budget.max_error_mm)
    say(progress, f"error budget {config.budget.max_error_mm:g} mm: {choice.point.describe()}, "
                  f"measured max error {choice.point.errors['max_mm']:.3g} mm ({path})")
    return config.with_values(choice.overrides)


def load_skeleton(config: SceneConfig, urdf_xml: str | None, progress: Callable[[str], None] | None = None):
    """(skeleton or None, the URDF text it was built from, the leaf shapes of the URDF's links) for
    skeleton.source: none, builtin, urdf_file, or robot_description (``urdf_xml``: the text received on that
    topic). The URDF is prepared first (skeleton/link_shapes.prepare_urdf: up axis, free root, leaf shapes)."""
    sk = config.skeleton
    source = sk.source
    if source == "none":
        return None, urdf_xml, {}
    urdf_path = None
    limits = UrdfLimits.of(sk)
    if source == "builtin":
        urdf_xml = default_humanoid().urdf
    elif source == "urdf_file":
        urdf_path = find_data_file(sk.urdf_file, URDF_MANIFEST, "skeleton.urdf_file")
        urdf_xml = read_urdf_file(urdf_path, limits)
    elif urdf_xml is None:
        raise ValueError("skeleton.source is 'robot_description': pass the URDF text received on that "
                         "topic (the node waits for it)")
    try:
        tree = check_urdf(urdf_xml, limits)     # before anything reads it (skeleton/urdf_check.py)
        say(progress, f"URDF checked: a tree of {tree.n_links} links and {tree.n_joints} joints from {tree.root!r}, "
                      f"{tree.depth} deep")
        prepared = prepare_urdf(urdf_xml, sk.up_axis, sk.root_joint,
                                leaf_shapes=body_kind(config.body.kind).leaf_shapes, urdf_file=urdf_path)
        for note in prepared.notes:
            say(progress, note)
        return Skeleton.from_urdf_string(prepared.urdf, limits.prepared()), prepared.urdf, prepared.leaf_shapes
    except UrdfError as exc:               # name the file the user can fix
        if source != "urdf_file":
            raise
        text = f"skeleton.urdf_file {sk.urdf_file!r}: {exc}"
        raise (UrdfRefused(exc.kind, text) if isinstance(exc, UrdfRefused) else UrdfError(text)) from exc


def jelly_bind_pose(config: SceneConfig, skeleton: Skeleton, progress: Callable[[str], None] | None = None
                    ) -> np.ndarray | None:
    """The configuration a jelly body on ``skeleton`` is built and bound in: None (the zero pose) unless
    skeleton.bind_pose / bind_joints say otherwise (body/fit.bind_configuration), e.g. frame 0 of the capture for
    a rig whose zero pose is no standing human."""
    s = config.skeleton
    if s.bind_pose in ("neutral", "auto") and not s.bind_joints:     # 'auto' finds a surface mesh's pose
        return None
    q = bind_configuration(skeleton, s.bind_pose, s.bind_joints, s.bind_angles, s.bind_bvh)
    say(progress, f"jelly body built in the bind pose (skeleton.bind_pose {s.bind_pose!r}"
                  + (f", {len(s.bind_joints)} joints set" if s.bind_joints else "") + ")")
    return q


def jelly_radii(skeleton: Skeleton, leaf_shapes: dict, body, progress: Callable[[str], None] | None = None,
                q: np.ndarray | None = None) -> tuple[dict[str, float], list[str]]:
    """({bone: capsule radius [m]}, bare bones) of a jelly body on ``skeleton`` (not the built-in humanoid): with
    body.flesh 'auto', radii by each bone's role in a human (skeleton/bone_roles.py), bare bones left out (they bind
    no flesh either: a vertex of the thigh must not follow the fingers of a hand hanging beside it) and named in one line;
    with 'uniform', or when the skeleton is not a human's (said in one line), body.bone_radius for every bone. A
    leaf with URDF shapes has radius 0 (its shapes are its flesh). The roles are read in the configuration ``q``
    (None: the zero pose)."""
    r = float(body.bone_radius)
    radii, bare = {name: r for name in skeleton.bone_names}, []
    if body.flesh == "auto":
        try:
            roles = label_skeleton(skeleton, q)
        except NotHumanoid as exc:
            say(progress, f"body.flesh 'auto': not a human skeleton ({exc}); every bone gets body.bone_radius "
                          f"{r:g} m (set body.flesh 'uniform' to skip this test)")
        else:
            radii, bare = flesh_radii(roles, body.target_tets)
            say(progress, roles.summary() + f"; thinnest flesh {min(radii.values()):.3g} m (1.25 voxels of "
                          f"~{body.target_tets} tets); body.flesh 'uniform' gives every bone body.bone_radius instead")
            for note in roles.notes:
                say(progress, f"warning: {note}")
            say(progress, f"bones left bare ({len(bare)}, covered by their neighbours' flesh): "
                          + (", ".join(f"{n} ({roles.role_of(n)})" for n in bare) if bare else "none"))
    return {name: 0.0 if name in leaf_shapes else radius for name, radius in radii.items()}, bare


@dataclass(frozen=True)
class BodyKind:
    """A kind of body a scene builds (``body.kind``): its declaration (body_kinds.py: the flags the configuration
    checks, where its builder is) and the builder, ``build(config, skeleton, urdf_xml, leaf_shapes, progress)``,
    which makes the scene's parts."""
    declaration: BodyDeclaration
    build: Callable[..., SceneParts]

    @property
    def name(self) -> str:
        return self.declaration.name

    @property
    def leaf_shapes(self) -> bool:
        """The skeleton's URDF is prepared with its leaf links' own shapes as flesh (skeleton/link_shapes.py)."""
        return self.declaration.leaf_shapes

    @property
    def needs_skeleton(self) -> bool:
        return self.declaration.needs_skeleton


BODY_KINDS = Registry("body kind")          # the kinds built so far, each loaded from its declaration once


def body_kind(name: str) -> BodyKind:
    """The declared body kind ``name`` (body_kinds.BODY_DECLARATIONS), its builder's module imported on first use;
    ValueError naming the choices for an undeclared one."""
    if name not in BODY_KINDS:
        if name not in BODY_DECLARATIONS:
            raise ValueError(f"body.kind = {name!r}: choose one of {', '.join(BODY_DECLARATIONS)}")
        declaration = BODY_DECLARATIONS[name]
        BODY_KINDS.register(name, BodyKind(declaration, load_object(declaration.builder)))
    return BODY_KINDS[name]


def build_jelly_man(config: SceneConfig, skeleton, urdf_xml, leaf_shapes, progress) -> SceneParts:
    source, body = config.skeleton.source, config.body
    bind_q = None
    bare: list[str] = []
    if source == "builtin":
        spec = default_humanoid()
    else:
        bind_q = jelly_bind_pose(config, skeleton, progress)
        radii, bare = jelly_radii(skeleton, leaf_shapes, body, progress, bind_q)
        spec = HumanoidSpec(urdf_xml, radii, leaf_shapes=leaf_shapes)
    # radii by role differ from bone to bone: keep each voxel nearest its own bone's axis (the binding's rule)
    axis_consistent = source != "builtin" and body.flesh == "auto"
    if body.skin == "smooth":
        say(progress, f"meshing the jelly man (~{body.target_tets} tets): voxels, skin on the blended capsules")
        mesh, reference = smooth_jelly_man_meshes(spec, target_tets=body.target_tets, q=bind_q,
                                                  axis_consistent=axis_consistent)
        voxels = reference
    else:
        say(progress, f"voxelizing the jelly man (~{body.target_tets} tets)")
        mesh = voxels = jelly_man_mesh(spec, target_tets=body.target_tets, q=bind_q, axis_consistent=axis_consistent)
        reference = None
    allowed = voxel_bones(spec, mesh, bind_q, voxels) if source != "builtin" else None
    # a jelly body of equal capsules on another skeleton has no flesh meant to hang free: its only vertices
    # beyond the outermost level are voxel corners just outside it, one-tet flaps that flutter on fast motion
    return SceneParts(config, mesh, np.zeros(mesh.n_vertices, dtype=bool), skeleton, urdf_xml,
                      bind_all=source != "builtin", bind_q=bind_q, bare_bones=tuple(bare), vertex_bones=allowed,
                      mass_reference=reference)


def build_robot_cover(config: SceneConfig, skeleton, urdf_xml, leaf_shapes, progress) -> SceneParts:
    body = config.body
    say(progress, f"covering the robot's links (~{body.target_tets} tets)")
    urdf_file = (find_data_file(config.skeleton.urdf_file, URDF_MANIFEST, "skeleton.urdf_file")
                 if config.skeleton.source == "urdf_file" else None)
    cover = robot_cover(urdf_xml, skeleton, thickness=body.cover_thickness, target_tets=body.target_tets,
                        source=body.cover_shapes, urdf_file=urdf_file, bare_radius=body.bone_radius,
                        max_triangles=body.cover_max_triangles)
    for note in cover.notes:
        say(progress, note)
    return SceneParts(config, cover.mesh, np.zeros(cover.mesh.n_vertices, dtype=bool), skeleton, urdf_xml,
                      cover=cover)


def build_volume_mesh(config: SceneConfig, skeleton, urdf_xml, leaf_shapes, progress) -> SceneParts:
    mesh = read_mesh(config.body.mesh_file)
    return SceneParts(config, mesh, np.zeros(mesh.n_vertices, dtype=bool), skeleton, urdf_xml)


def build_surface(config: SceneConfig, skeleton, urdf_xml, leaf_shapes, progress) -> SceneParts:
    surface = build_surface_body(config, skeleton, progress)
    return SceneParts(config, surface.mesh, np.zeros(surface.mesh.n_vertices, dtype=bool), skeleton, urdf_xml,
                      surface=surface, bare_bones=surface.unbound)


def build_paper_shape(config: SceneConfig, skeleton, urdf_xml, leaf_shapes, progress) -> SceneParts:
    """One of the paper's shapes; without a skeleton its bottom fifth is held when body.fix_bottom asks."""
    mesh = paper_mesh(config.body.kind, config.body.scale)
    fixed = np.zeros(mesh.n_vertices, dtype=bool)
    if skeleton is None and config.body.fix_bottom:
        z = mesh.vertices[:, 2]
        fixed = z <= z.min() + 0.2 * np.ptp(z)
    return SceneParts(config, mesh, fixed, skeleton, urdf_xml)




def scene_parts(config: SceneConfig, urdf_xml: str | None = None,
                progress: Callable[[str], None] | None = None) -> SceneParts:
    """Everything the config asks for (and nothing else): the error budget's choice, the skeleton, the body
    (its kind's ``build``: ``body_kind``)."""
    if config.budget.max_error_mm > 0:
        config = apply_error_budget(config, progress)
    kind = body_kind(config.body.kind)
    skeleton, urdf_xml, leaf_shapes = load_skeleton(config, urdf_xml, progress)
    if kind.needs_skeleton and skeleton is None:
        raise ValueError(f"body.kind {kind.name!r} is built around a skeleton, but skeleton.source is 'none': "
                         "choose a skeleton source or a paper shape / mesh body")
    return kind.build(config, skeleton, urdf_xml, leaf_shapes, progress)
