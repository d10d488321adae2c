"""The parts a scene runs, wired from the parts scene_build chose. No ROS.

``set_up(parts)`` does the whole set-up: the FEM model and its integrator, the surface the outputs show, the
anchors, the body's binding to the skeleton (bind pose, levels, skipped bones, pieces no bone reaches, the
driver) and the joint inputs (joint map, joint stream). ``warm_up`` loads the compiled kernels before the first
real step. scene.Scene receives the result and only runs it (scene.Scene.build calls all three in order).
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from .body.anchors import anchor_constraints
from .body.binding import Binding, bind_to_skeleton, segment_distance
from .body.bone_reach import describe as describe_reach, end_bones, reach_to_skin
from .body.constraints import LevelGains, LineConstraint, PointConstraint, point_targets
from .body.driver import SkeletonDriver
from .body.link_binding import bind_to_links
from .body.surface_body import SurfaceBody, unbound_islands
from .config import SceneConfig
from .fem.integrators import make_integrator
from .fem.integrators.base import Integrator
from .fem.linear.assembly import lumped_mass
from .fem.mass_scaling import scale_mass, scale_to_reference
from .fem.model import Attachments, Control, FemModel, State, build_model
from .fem.mesh.tet_mesh import TetMesh, boundary_triangles
from .fem.volume_pressure import VolumePressure, volume_pressure
from .numba_cache import is_cached
from .scene_build import SceneParts, integrator_choice, material_of, say
from .skeleton.bone_roles import NotHumanoid, label_skeleton
from .skeleton.joint_limits import joint_limits
from .skeleton.joint_map import JointMap
from .skeleton.joint_stream import JointStreamInterpolator
from .skeleton.kinematics import Skeleton

WARM_UP_STEPS = 40      # steps on a throw-away state: the kernels load and the integrator settles on its threads


@dataclass
class RunningParts:
    """What scene.Scene runs (set_up). Without a skeleton, binding, driver, joints and stream are None."""
    config: SceneConfig             # with the error budget's choice applied
    model: FemModel
    integrator: Integrator          # the method: step(state, control, h)
    skeleton: Skeleton | None
    urdf_xml: str | None            # the URDF the skeleton was built from (prepared: up axis, root, leaf shapes)
    surface_body: SurfaceBody | None    # of a surface body: bind pose, depth under the skin
    bind_all: bool                  # the outermost binding level reaches every vertex (a capsule body)
    anchors: list                   # body.constraints PointConstraint / LineConstraint of anchors.points
    anchored: Attachments | None    # the anchors' fixed targets when no skeleton drives the body
    binding: Binding | None
    driver: SkeletonDriver | None   # the skeleton's constraints on the body, the anchors' among them
    joints: JointMap | None         # joint-state names and values -> the skeleton's q, from the bind pose
    stream: JointStreamInterpolator | None     # the accepted joint samples, sampled at the step times
    triangles: np.ndarray           # (t, 3) the body's boundary triangles, into its vertices
    surface_vertices: np.ndarray    # (k,) the vertices on the boundary, sorted
    surface_triangles: np.ndarray   # (t, 3) the boundary triangles, into surface_vertices
    rest_volume: float              # [m^3]
    pressure: VolumePressure | None = None  # the whole volume's pressure (material.volume_stiffness > 0)


def set_up(parts: SceneParts, progress: Callable[[str], None] | None = None) -> RunningParts:
    """The model, integrator, anchors, binding and joint inputs of ``parts``, wired (not warmed up: warm_up)."""
    config, mesh, skeleton = parts.config, parts.mesh, parts.skeleton
    say(progress, f"assembling {mesh.n_tets} tets / {mesh.n_vertices} vertices")
    model = build_model(mesh, material_of(config), fixed=parts.fixed,
                        gravity=(0.0, 0.0, float(config.physics.gravity)), min_quality=config.body.min_tet_quality)
    say(progress, model.quality.summary())
    if parts.mass_reference is not None:
        model, scaling = scale_to_reference(model, parts.mass_reference)
        say(progress, scaling.summary() + ": the critical step of the voxels the skin was moved from")
    model = scaled_mass(config, model, skeleton is not None, progress)
    method, options = integrator_choice(config)
    say(progress, f"setting up method '{method}'"
                  f"{' with ' + config.warping_model + ' warping' if options.get('warp') else ''}")
    integrator = make_integrator(method, model, **options)
    anchors = anchor(config, model.rest, skeleton, progress)
    anchored = binding = driver = joints = stream = None
    triangles, surface_vertices, surface_triangles = boundary_surface(mesh)
    if skeleton is not None:
        q0 = parts.surface.bind_q if parts.surface is not None else \
            parts.bind_q if parts.bind_q is not None else skeleton.neutral()
        binding = (bind(config, model, skeleton, q0, anchors, parts.surface, parts.bind_all, progress,
                        triangles=triangles, bare=parts.bare_bones, allowed=parts.vertex_bones)
                   if parts.cover is None else bind_cover(config, model, skeleton, q0, parts.cover, progress))
        driver = skeleton_driver(config, binding, model.rest, skeleton, anchors, model.mesh.tets)
        if driver.crush is not None:
            say(progress, driver.crush.summary())
        joints, stream = joint_inputs(config, skeleton, q0)
    elif anchors:                   # world points: their targets, once
        index, x, v, a, kp, kd = point_targets(anchors, model.rest)
        anchored = Attachments(index, x - model.rest[index], v, a, kp, kd)
    pressure = volume_pressure(model, config.material.volume_stiffness, config.physics.step, triangles)
    if pressure is not None:
        say(progress, pressure.summary(config.physics.step, model.mass))
    return RunningParts(config=config, model=model, integrator=integrator, skeleton=skeleton,
                        urdf_xml=parts.urdf_xml, surface_body=parts.surface, bind_all=parts.bind_all,
                        anchors=anchors, anchored=anchored, binding=binding, driver=driver, joints=joints,
                        stream=stream, triangles=triangles, surface_vertices=surface_vertices,
                        surface_triangles=surface_triangles, rest_volume=float(mesh.volumes().sum()),
                        pressure=pressure)


def scaled_mass(config: SceneConfig, model: FemModel, driven: bool,
                progress: Callable[[str], None] | None = None) -> FemModel:
    """``model`` with the mass physics.mass_scaling allows added for one explicit sub-step a step (fem/mass_scaling.py),
    planned with the stiffest gains the skeleton (``driven``) or the anchors will attach; unchanged when off or for an
    implicit or modal method."""
    p = config.physics
    if p.mass_scaling <= 0.0 or config.method not in ("clustered", "standard_explicit"):
        return model
    gains = [(max(config.binding.kp), max(config.binding.kd))] if driven else []
    if config.anchors.points:
        gains.append((config.anchors.kp, config.anchors.kd))
    kp, kd = (max(g[0] for g in gains), max(g[1] for g in gains)) if gains else (0.0, 0.0)
    model, done = scale_mass(model, p.step / p.safety, p.mass_scaling, kp, kd)
    say(progress, done.summary())
    return model


def boundary_surface(mesh: TetMesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(boundary triangles (t, 3) into the mesh's vertices, the boundary's vertices (k,) sorted, the same
    triangles into those k vertices): the surface the outputs show."""
    triangles = boundary_triangles(mesh)
    surface_vertices = np.unique(triangles)
    remap = np.full(mesh.n_vertices, -1, dtype=np.int64)
    remap[surface_vertices] = np.arange(surface_vertices.size)
    return triangles, surface_vertices, remap[triangles]


def anchor(config: SceneConfig, rest: np.ndarray, skeleton: Skeleton | None,
           progress: Callable[[str], None] | None = None) -> list:
    """The constraints of the scene's anchors: point, or line where anchors.sliding says so (none unless
    anchors.points lists some)."""
    c = config.anchors
    if not c.points:
        return []
    anchors = anchor_constraints(rest, c.points, c.radius, c.kp, c.kd, c.bones,
                                 skeleton.bone_names if skeleton is not None else None, c.sliding)
    slide = sum(1 for s in c.sliding if s)
    say(progress, f"anchoring {len(anchors)} vertices at {len(c.points) // 3} points"
                  + (f" ({slide} sliding along their bones)" if slide else ""))
    return anchors


def bind(config: SceneConfig, model: FemModel, skeleton: Skeleton, q0: np.ndarray, anchors: list,
         surface: SurfaceBody | None, bind_all: bool, progress: Callable[[str], None] | None = None,
         *, triangles: np.ndarray, bare: tuple[str, ...] = (), allowed: np.ndarray | None = None) -> Binding:
    """The body's vertices bound to the bones of ``skeleton`` posed at ``q0`` (its bind pose), in the levels of
    binding.level_radii (fractions of the flesh's depth with binding.relative_levels), without the bones of
    binding.skip_bones nor the ``bare`` bones of a jelly body (they have no flesh). ``bind_all``: the outermost
    level is widened to reach every vertex. ``allowed`` (n, nb): the bones each vertex may bind to (a jelly body
    on a URDF: the bones of its own voxels). A surface body's
    pieces that no bone and no anchor reaches are carried by their nearest bone when small, else refused
    (hold_islands), and its end bones reach into their flesh (body/bone_reach.py) up to its boundary
    ``triangles`` (the mesh's outward boundary_triangles)."""
    b = config.binding
    poses = skeleton.forward(q0, np.zeros(skeleton.nv))
    starts, ends = skeleton.bone_segments(q0)
    say(progress, f"binding {model.n_vertices} vertices to {len(skeleton.bone_names)} bones")
    depth = surface.depth if b.relative_levels else None
    mask = None
    if b.skip_bones:
        unknown = [name for name in b.skip_bones if name not in skeleton.bone_names]
        if unknown:
            raise ValueError(f"binding.skip_bones names {unknown}, which are not bones of this skeleton; its bones "
                             f"are {', '.join(skeleton.bone_names)}")
        mask = np.array([name not in b.skip_bones for name in skeleton.bone_names])
    if bare:
        mask = (np.ones(len(skeleton.bone_names), dtype=bool) if mask is None else mask) & \
            np.array([name not in bare for name in skeleton.bone_names])
    radii = list(b.level_radii)
    if bind_all:
        kept = np.ones(len(skeleton.bone_names), dtype=bool) if mask is None else mask
        ok = np.broadcast_to(kept, (model.n_vertices, kept.size))
        if allowed is not None:
            mine = allowed & kept
            ok = mine | (~mine.any(axis=1, keepdims=True) & kept)
        dist = np.where(ok, segment_distance(model.rest, starts, ends), np.inf)
        reach = float(dist.min(axis=1).max()) * (1 + 1e-9)
        if reach > radii[-1]:
            say(progress, f"the outermost binding level reaches {reach:.3f} m instead of {radii[-1]:g} m: every "
                          "vertex of the capsule body is bound (no one-tet flaps left free)")
            radii[-1] = reach
    if surface is not None:         # a character's end bones reach on into their flesh (body/bone_reach.py)
        binds = np.ones(len(skeleton.bone_names), dtype=bool) if mask is None else mask
        nearest = np.argmin(np.where(binds, segment_distance(model.rest, starts, ends), np.inf), axis=1)
        share = lumped_mass(model.mesh, 1.0)                # each vertex's share of the volume
        ends, reach, turn = reach_to_skin(starts, ends, end_bones(skeleton.bone_parent, binds), model.rest,
                                          triangles, flesh=(model.rest, share, nearest))
        say(progress, describe_reach(skeleton.bone_names, reach, turn))
    binding = bind_to_skeleton(model.rest, starts, ends, radii, mask,
                               rest_rotation=poses.rotation, rest_translation=poses.translation,
                               bone_names=skeleton.bone_names, warn=False, surface_depth=depth, allowed=allowed)
    if surface is not None:
        binding = hold_islands(model, binding, anchors, progress)
    return binding


def bind_cover(config: SceneConfig, model: FemModel, skeleton: Skeleton, q0: np.ndarray, cover,
               progress: Callable[[str], None] | None = None) -> Binding:
    """A robot cover's vertices bound each to its own link's bone (body/link_binding.py), in as many levels as
    binding.level_radii has: level 0 on or in the link (within half a voxel of its surface), the outer ones the
    skin, every vertex bound."""
    poses = skeleton.forward(q0, np.zeros(skeleton.nv))
    starts, ends = skeleton.bone_segments(q0)
    binding = bind_to_links(model.rest, cover.bone, cover.depth, len(config.binding.level_radii),
                            core=0.5 * cover.spacing, skin=cover.thickness, starts=starts, ends=ends,
                            rest_rotation=poses.rotation, rest_translation=poses.translation)
    say(progress, f"binding {model.n_vertices} vertices each to its own link: {binding.summary()}")
    return binding


def skeleton_driver(config: SceneConfig, binding: Binding, rest: np.ndarray, skeleton: Skeleton,
                    anchors: list, tets: np.ndarray | None = None) -> SkeletonDriver:
    """What turns the skeleton's poses into the body's constraints: the binding's levels with the gains of
    binding.kp / kd (the innermost kinematic with binding.kinematic_core, the outer binding.sliding_levels sliding
    along their bones, falling where the targets crush the elements ``tets`` with binding.crush_release), and the
    anchors, point or line."""
    b = config.binding
    return SkeletonDriver(binding, rest, LevelGains(kp=tuple(b.kp), kd=tuple(b.kd)), kinematic=b.kinematic_core,
                          bone_names=skeleton.bone_names, sliding_levels=b.sliding_levels,
                          points=[a for a in anchors if isinstance(a, PointConstraint)],
                          lines=[a for a in anchors if isinstance(a, LineConstraint)],
                          tets=tets if b.crush_release > 0 else None, crush_floor=b.crush_release,
                          crush_held=digit_bones(skeleton) if b.crush_release > 0 else None)


def digit_bones(skeleton: Skeleton) -> np.ndarray:
    """The bones a crush release keeps holding: a human skeleton's fingers and toes by their role in the tree
    (skeleton/bone_roles.py). Their folds are a few elements across with no flesh around them to carry a vertex
    let go: a coarse hand whose finger bones crush it lets its whole flesh go, and the inverted elements throw it
    off (mesh2motion's A-pose on the Mixamo rig at 1500 tets: 0.43 m from the hand in 8 ms). Empty for a skeleton
    that is not a human's."""
    try:
        roles = label_skeleton(skeleton)
    except NotHumanoid:
        return np.zeros(0, dtype=np.int64)
    return np.array([k for k, r in enumerate(roles.roles) if r in ("finger", "toe")], dtype=np.int64)


ISLAND_SHARE = 0.05     # a loose piece of a surface body up to this share of its vertices is carried by its bone


def hold_islands(model: FemModel, binding: Binding, anchors: list,
                 progress: Callable[[str], None] | None = None) -> Binding:
    """``binding`` with every small piece of a surface body that no bone reaches (no vertex in the innermost
    level: relative levels bind the skin of any piece at its outer level) and no anchor holds carried by the bones
    it is bound to: its bound vertices put in the innermost level (a mesh's loose parts, fingers or eyes modelled
    apart from the body, tetrahedralized as pieces of their own). A piece beyond ISLAND_SHARE of the body's
    vertices, or with no vertex bound at all, would be dragged, not carried: refused."""
    driven = binding.level == 0
    driven[[a.vertex for a in anchors]] = True
    islands = unbound_islands(model.mesh.tets, model.n_vertices, driven)
    if not islands:
        return binding
    level = binding.level.copy()
    for size, index in islands:
        held = index[binding.level[index] >= 0]
        if size > ISLAND_SHARE * model.n_vertices or held.size == 0:
            centre = model.rest[index].mean(axis=0)
            raise ValueError(f"{len(islands)} piece(s) of the surface body are reached by no bone and no anchor; "
                             f"one has {size} vertices ({size / model.n_vertices:.1%} of the body, more than "
                             f"{ISLAND_SHARE:.0%} are not carried whole by a bone) around "
                             f"({', '.join(f'{x:.3f}' for x in centre)}) m: raise binding.level_radii, or hold it "
                             "with anchors.points / anchors.bones")
        level[held] = 0
    sizes = sorted((size for size, _ in islands), reverse=True)
    say(progress, f"{len(islands)} loose piece(s) of the surface ({', '.join(map(str, sizes))} vertices) reached by "
                  "no bone's core: carried whole by the bones they are bound to")
    return replace(binding, level=level)


def joint_inputs(config: SceneConfig, skeleton: Skeleton, q0: np.ndarray) -> tuple[JointMap, JointStreamInterpolator]:
    """(joint map starting at ``q0``, joint stream): what takes the skeleton's joint states, checked as the
    input.* parameters say (and against the URDF's joint limits: skeleton/joint_limits.py)."""
    c = config.input
    limits = joint_limits(skeleton.urdf, skeleton.joint_names, c.joint_limit_margin, skeleton.root_joint_mask())
    joints = JointMap(skeleton.joint_names, q0, max_names=c.max_names, limits=limits)
    stream = JointStreamInterpolator(skeleton.joint_names, revolute=skeleton.revolute_mask(),
                                     max_age=c.max_age, max_future=c.max_future,
                                     teleport_distance=c.teleport_distance, teleport_speed=c.teleport_speed,
                                     prismatic=~skeleton.revolute_mask(),
                                     max_root_distance=c.max_root_distance, max_joint_speed=c.max_joint_speed,
                                     balls=skeleton.ball_joints())
    return joints, stream


def warm_up(parts: RunningParts, control: Callable[[State], Control], h: float,
            progress: Callable[[str], None] | None = None, steps: int = WARM_UP_STEPS) -> None:
    """Load the compiled kernels (and let the integrator settle on serial or threaded) on a throw-away state,
    so the first real steps are not a second-long stall that drops inputs. ``control(state)``: the constraints
    the first real steps will get (the anchored build is another compiled build than the free one); the
    driver's history is reset after."""
    if any(is_cached(k) is False for k in getattr(parts.integrator, "kernels", ())):
        say(progress, "compiling the step's kernels into numba's cache (the first start of this code on this "
                      "machine: 15-30 s on 2 cores, once; later starts load them in about a second)")
    else:
        say(progress, "loading compiled kernels")
    state = State.rest(parts.model)
    first = control(state)
    for _ in range(2):              # a driver's third control on is its streaming path, another compiled kernel
        control(state)
    for _ in range(steps):
        parts.integrator.step(state, first, h)
    if parts.driver is not None:
        parts.driver.reset()
    if parts.stream is not None:
        parts.stream.load_kernels()
    parts.integrator.material_model.stress(parts.model, state.u)
