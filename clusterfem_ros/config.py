"""The scene configuration: every parameter typed, described, range-checked once, at the edge.

The same table serves the ROS node (declared as parameters with descriptors, so rclpy refuses
out-of-range values itself) and headless runs (``load_scene_file`` reads the ROS 2 parameter YAML).
A scene says what exists: outputs and features it does not ask for are neither built nor computed.
"""
from __future__ import annotations

import difflib
import re
import sys
from dataclasses import dataclass, field, fields, replace
from functools import cached_property
from pathlib import Path
from typing import Any

import yaml

from .body_kinds import BODIES, BODY_DECLARATIONS
from .errors import ClusterFemError
from .fem.linear.material import (DEFAULT_DENSITY, DEFAULT_MASS_DAMPING, DEFAULT_POISSON_RATIO,
                                  DEFAULT_STIFFNESS_DAMPING, DEFAULT_YOUNG_MODULUS)
from .fem.materials.warping_models import (ACKNOWLEDGEMENT, AUTO, DECLARED, WARPING_MODELS, auto_model, declared,
                                           explicit_only_refusal, stretch_plan_refusal, unbounded_refusal,
                                           undamped_corotation_refusal, unacknowledged_undamped)
from .skeleton.bvh_placement import AXES as BVH_AXES, parse_unit
from .skeleton.mounting import ROOT_JOINTS, UP_AXES
from .skeleton.urdf_check import (CEILING_BYTES, CEILING_DEPTH, CEILING_LINKS, CEILING_MESHES, DEFAULT_MAX_BYTES,
                                  DEFAULT_MAX_DEPTH, DEFAULT_MAX_JOINTS, DEFAULT_MAX_LINKS, DEFAULT_MAX_MESHES,
                                  MAX_TRIANGLES)


METHODS = ("clustered", "standard_explicit", "implicit_direct", "implicit_cg", "modal")
SKELETONS = ("builtin", "urdf_file", "robot_description", "none")
COLORMAPS = ("turbo", "viridis", "coolwarm")
BVH_UP = ("auto",) + BVH_AXES     # a BVH file's up axis: found from its legs, or a signed file axis
NODE_NAME = "clusterfem"


@dataclass(frozen=True)
class Param:
    name: str
    default: Any
    description: str
    lo: float | None = None          # numeric range (inclusive), checked by rclpy and by validate()
    hi: float | None = None
    choices: tuple[str, ...] | None = None
    item: type = float               # element type of a list parameter
    length_unit: bool = False        # text naming a length unit, or metres per unit as a number (parse_unit)
    or_auto: bool = False            # a number in [lo, hi], or 'auto' (the scene resolves it: SceneConfig.resolved)


PARAMS: tuple[Param, ...] = (
    Param("body.kind", "jelly_man", "soft body: built around the skeleton (jelly_man: capsules around bones; robot_cover: the links' own shapes with a skin), a paper shape, or a mesh file", choices=BODY_DECLARATIONS.names()),
    Param("body.mesh_file", "", "volume mesh (.msh/.vtu/.vtk/.mesh) when body.kind is 'mesh', in the skeleton's rest pose"),
    Param("body.target_tets", 4800, "approximate tet count of the jelly man, of a robot cover, or of a surface body (within 20 %)", 100, 400000),
    Param("body.surface_file", "", "triangle surface (.obj/.stl/.ply/.glb) of a character when body.kind is 'surface': a path, "
          "or a path under $CLUSTERFEM_DATA, ../shared/data or the user data folder; tetrahedralized with fTetWild, cached"),
    Param("body.surface_group", "auto", "the OBJ group of body.surface_file to use: auto (an OBJ's largest group when "
          "it is closed, as a body beside its helper groups; else the whole file), a group name, or '' (the whole file)"),
    Param("body.surface_unit", "auto", "length unit of body.surface_file: auto (the unit in which the surface is a "
          "standing human's height: body/mesh_frame.py), m, dm, cm, mm, inch, or metres per file unit as a number",
          length_unit=True),
    Param("body.bone_radius", 0.05, "capsule radius around each bone of a jelly body on a skeleton other than the built-in humanoid [m]", 0.005, 1.0),
    Param("body.flesh", "auto", "jelly body on a skeleton other than the built-in humanoid: 'auto' tells a human's bones "
          "from the tree and its rest shape (skeleton/bone_roles.py) and gives each a radius in proportion to the "
          "height (falls back to 'uniform', saying why, when the skeleton is not a human's); 'uniform' gives every "
          "bone body.bone_radius", choices=("auto", "uniform")),
    Param("body.cover_thickness", 0.02, "body.kind 'robot_cover': the skin around each link's own shapes (at least "
          "0.87 voxel edges, so the skin has no gaps) [m]", 0.001, 0.5),
    Param("body.cover_shapes", "collision", "body.kind 'robot_cover': the links' shapes it is built around, "
          "'collision' or 'visual' (a link without the one takes the other)", choices=("collision", "visual")),
    Param("body.cover_max_triangles", MAX_TRIANGLES, "body.kind 'robot_cover': a URDF whose link shapes have more "
          "triangles than this in all is refused (~0.6 kB each while the cover is built; example-robot-data's robots "
          "have at most 0.4 M collision triangles, 1.03 M visual ones: b1-z1)", 1000, 20_000_000),
    Param("body.scale", 1.0, "refinement of the paper shapes (1 = the paper's sizes)", 0.25, 8.0),
    Param("body.fix_bottom", True, "hold the lowest 20% of a paper shape fixed (shapes without skeleton)"),
    Param("body.min_tet_quality", 1e-8, "refuse a mesh with a tet of lower shape quality (6 sqrt2 V / l_rms^3, 1 = "
          "regular; fem/mesh/tet_quality.py): a nearly flat tet makes the explicit step take thousands of sub-steps; 0 "
          "accepts any shape", 0.0, 0.99),
    Param("body.skin", "smooth", "skin of the jelly man: 'smooth' (its surface vertices on the bone capsules blended "
          "at the joints, skeleton/smooth_body.py, its masses raised where its thinner tets would shorten the step: "
          "fem/mass_scaling.py) or 'voxel' (the voxel steps)", choices=("smooth", "voxel")),
    # the material defaults are Material()'s (fem/linear/material.py says why these values; tests/test_scene.py)
    Param("material.young_modulus", DEFAULT_YOUNG_MODULUS, "Young's modulus E [Pa]", 1.0, 1.0e10),
    Param("material.poisson_ratio", DEFAULT_POISSON_RATIO, "Poisson ratio nu [-]", 0.0, 0.499),
    Param("material.density", DEFAULT_DENSITY, "density [kg/m^3]", 1.0, 1.0e5),
    Param("material.mass_damping", DEFAULT_MASS_DAMPING, "Rayleigh xi [1/s]: D = xi M + zeta K", 0.0, 1.0e3),
    Param("material.stiffness_damping", DEFAULT_STIFFNESS_DAMPING, "Rayleigh zeta [s]", 0.0, 1.0),
    Param("material.volume_stiffness", AUTO, "the flesh's near-incompressibility for the body's whole volume: one "
          "pressure p = kappa K (V0 - V) / V0 on its surface, kappa this multiple of the elements' bulk modulus K "
          "(fem/volume_pressure.py; keeps the volume where the bones' targets crush a folded joint; 0 = off, "
          "nothing built); 'auto': 2 on flesh on a skeleton (jelly_man, surface), 0 on the paper shapes, volume "
          "meshes and robot covers", 0.0, 1000.0, or_auto=True),
    Param("method", "clustered", "integrator", choices=METHODS),
    Param("budget.max_error_mm", 0.0, "if > 0: method, physics.step, warping and modal.k become the cheapest measured point whose max vertex error is within this budget [mm] (0 = off)", 0.0, 1000.0),
    Param("budget.measured_points", "", "CSV of measured (method, step, error, cost) points for the budget choice; '' = the shipped clusterfem_ros/data/speed_error.csv"),
    Param("modal.k", 30, "number of modes for method 'modal'", 1, 2000),
    Param("warping", True, "stiffness warping: removes the linear model's volume growth under rotation"),
    Param("warping_model", AUTO, "'auto': 'neohookean' on method 'clustered', 'element' on the others and with "
          "an error budget; 'neohookean': stable Neo-Hookean elements, no rotation, an energy smooth through "
          "inversion (method 'clustered' only; fem/materials/neohookean.py); 'element': per-element corotation, the "
          "gradient of an energy (cannot feed energy in while no element is inverted); 'vertex': the paper's "
          "per-vertex warping (eq. 10), for comparison: not bounded, refused unless physics.allow_unbounded_warping",
          choices=DECLARED.names(AUTO)),
    Param("physics.step", 1.0e-3, "physics step h [s]", 1.0e-6, 0.1),
    Param("physics.timer_hz", 100.0, "wall clock: the physics thread steps up to the clock on every joint state and at least this often; a batch of steps lasts at most 0.7 / this, and the state a batch ends on goes to the outputs when their last snapshot is 1 / this old", 1.0, 2000.0),
    Param("physics.safety", 0.8, "explicit sub-steps keep h_sub <= safety * h_crit", 0.05, 1.0),
    Param("physics.mass_scaling", 0.0, "explicit methods: add lumped mass to the light, stiff vertices whose critical step is shorter than one sub-step of physics.step (fem/mass_scaling.py), at most this share of the body's mass (0 = off; the log line says how many vertices and how much)", 0.0, 0.2),
    Param("physics.plan_stretch", True, "explicit with warping: plan the sub-steps for the elements' stretch (fem/materials/stretch.py; the Neo-Hookean elements each against their own rest frequency; keeps an undamped torn vertex bounded) instead of the linear stiffness alone"),
    Param(ACKNOWLEDGEMENT, False, "true: accept warping_model 'vertex' (the paper's per-vertex warping), and "
          "'element' on an explicit method without damping, knowing their energy can grow without bound (torn "
          "vertices, slivers; benchmarks/stability_table.py); 'vertex' runs with a warning. false: such a scene is "
          "refused"),
    Param("physics.max_substeps", 64, "explicit methods refuse a step needing more sub-steps than this; implicit with warping sub-steps up to it where rotations turn fast", 1, 100000),
    Param("physics.clock", "wall", "'wall': physics follows the ROS clock; 'input': it follows the newest joint-state "
          "stamp (deterministic replay of a recording)", choices=("wall", "input")),
    Param("physics.input_wait", 0.0, "wall clock: physics may lag the clock this long [s] waiting for late joint states instead of stepping past the newest one and jumping when they come (0: never waits, physics keeps the clock)", 0.0, 10.0),
    Param("physics.max_catchup_steps", 250, "physics may run behind its inputs by this many steps (slow motion); beyond, the gap is dropped and the body re-placed on the skeleton", 1, 100000),
    Param("physics.gravity", -9.81, "gravity along world z [m/s^2]", -100.0, 100.0),
    Param("skeleton.source", "builtin", "skeleton URDF: built-in humanoid, a file, the robot_description topic, or none", choices=SKELETONS),
    Param("skeleton.urdf_file", "", "URDF path when skeleton.source is 'urdf_file'"),
    Param("skeleton.up_axis", "z", "the URDF's up axis, turned onto world z (gravity along the legs): y for ISB / "
          "biomechanical models", choices=UP_AXES),
    Param("skeleton.root_joint", "auto", "'free': add root_x/y/z and root_yaw/pitch/roll joints above the URDF's "
          "root (the players' root pose moves it); 'fixed': use the URDF's joints as they are; 'auto': free when "
          "the URDF has no prismatic joint", choices=ROOT_JOINTS),
    Param("skeleton.bind_pose", "neutral", "pose a surface body was modelled in, or a jelly body on a skeleton other "
          "than the built-in one is built in: the URDF's zero pose, frame 0 of skeleton.bind_bvh (the capture "
          "the player plays), or 'auto': a surface body's found from the mesh and the skeleton, each limb of the "
          "skeleton's rest turned onto the mesh's, finger and toe bones outside the mesh left without flesh "
          "(body/auto_bind.py); any other body's as 'neutral'", choices=("neutral", "first_frame", "auto")),
    Param("skeleton.bind_bvh", "", "BVH file whose frame 0 is the bind pose when skeleton.bind_pose is 'first_frame': "
          "a path, or a name under $CLUSTERFEM_DATA, ../shared/data or the user data folder"),
    Param("skeleton.bvh_unit", "auto", "length unit of the BVH file played (the player's 'unit' unless its own section "
          "sets it) and of skeleton.bind_bvh: auto (found from the skeleton: a standing human), m, cm, mm, inch, cmu "
          "(0.056444 m) or metres per file unit (a number; a string such as '0.01' in a ROS parameter file)",
          length_unit=True),
    Param("skeleton.bvh_up", "auto", "up axis of the BVH file played (the player's 'up' unless its own section sets "
          "it) and of skeleton.bind_bvh: auto (found from the legs of the rest pose) or X, Y, Z, -X, -Y, -Z",
          choices=BVH_UP),
    Param("skeleton.bind_joints", [], "joints set to skeleton.bind_angles on top of skeleton.bind_pose (e.g. the arms "
          "of an A-pose mesh on a T-pose skeleton)", item=str),
    Param("skeleton.bind_angles", [], "per joint of skeleton.bind_joints, its bind angle [rad] (or position [m])"),
    Param("skeleton.fit", "auto", "how the surface sits on the skeleton: 'auto' scales it so the skeleton spans 93 % "
          "of its height, centres it, then moves and scales it so the bones lie 1 cm under the skin (least squares); "
          "'manual' uses body.surface_unit and skeleton.fit_offset", choices=("auto", "manual")),
    Param("skeleton.fit_up", "auto", "the surface file's up axis, from the feet to the head: auto (read from its "
          "shape: body/mesh_frame.py) or Y (most modelling tools), Z, -Y (a file upside down), ...", choices=BVH_UP),
    Param("skeleton.fit_forward", "auto", "the surface file's forward axis, the way the character faces: auto (the "
          "way its feet reach out) or -Z (a character modelled facing away along Z), X, ...; with skeleton.bind_pose "
          "'auto' the feet's long axes decide when they point clearly", choices=BVH_UP),
    Param("skeleton.fit_offset", [0.0, 0.0, 0.0], "with skeleton.fit 'manual': where the file's origin goes in the "
          "skeleton's bind-pose frame [m]"),
    Param("skeleton.fit_tolerance", 0.02, "a bone may leave the surface body by this much before the fit is refused [m]", 0.0, 1.0),
    # the URDF check before Pinocchio (skeleton/urdf_check.py): defaults that fit every robot of
    # example-robot-data (at most 211 KB, 130 links, 21 joints deep, 129 meshes) and BVH skeletons with margin
    Param("skeleton.max_urdf_bytes", DEFAULT_MAX_BYTES, "a URDF larger than this is refused unread [bytes]", 1000, CEILING_BYTES),
    Param("skeleton.max_links", DEFAULT_MAX_LINKS, "a URDF with more links than this is refused", 1, CEILING_LINKS),
    Param("skeleton.max_joints", DEFAULT_MAX_JOINTS, "a URDF with more joints than this is refused", 0, CEILING_LINKS),
    Param("skeleton.max_depth", DEFAULT_MAX_DEPTH, "a URDF with a link more joints than this below its root is refused", 1, CEILING_DEPTH),
    Param("skeleton.max_meshes", DEFAULT_MAX_MESHES, "a URDF with more <mesh> references than this is refused", 0, CEILING_MESHES),
    Param("binding.level_radii", [0.035, 0.06], "nested constraint levels: distance to the bone axis [m], increasing"),
    Param("binding.relative_levels", False, "binding.level_radii are fractions (0, 1] of the local flesh thickness, "
          "bone to skin, instead of metres (surface bodies: thin fingers and thick thighs both get a core)"),
    Param("binding.skip_bones", [], "bones that bind no flesh (their flesh goes to the nearest other bone), e.g. a "
          "capture's noisy finger bones; [] = every bone binds", item=str),
    Param("binding.kp", [4.0e4, 4.0e3], "per-level position gain [1/s^2]"),
    Param("binding.kd", [400.0, 120.0], "per-level velocity gain [1/s]"),
    Param("binding.kinematic_core", False, "prescribe the innermost level exactly instead of by forces"),
    Param("binding.sliding_levels", 0, "the outermost this many levels slide along their bone's axis (the paper's "
          "line constraints) between its ends instead of following points on the bone", 0, 16),
    Param("binding.crush_release", 0.0, "a bound vertex lets go of its target as its bones' targets crush its elements "
          "that span bones (a joint folded hard): its gains fall from full at the elements' rest volume to 0 at this "
          "share of it (body/crush_release.py; fingers and toes keep theirs); 0 = off, the gains of binding.kp / kd "
          "everywhere", 0.0, 0.95),
    Param("anchors.points", [], "world points x, y, z, ... of the body's rest pose [m]: the vertices within anchors.radius "
          "of each are held there by point constraints ([] = none)"),
    Param("anchors.bones", [], "per anchor point, the bone that carries it ('' = fixed in the world); [] = all in the "
          "world", item=str),
    Param("anchors.sliding", [], "per anchor point, true: its vertices slide along their bone's axis between the "
          "bone's ends (the paper's line constraint) instead of being held at the point; [] = none slide", item=bool),
    Param("anchors.radius", 0.02, "vertices within this distance of an anchor point are held [m]", 1.0e-4, 10.0),
    Param("anchors.kp", 4.0e4, "anchor position gain [1/s^2]", 0.0, 1.0e9),
    Param("anchors.kd", 400.0, "anchor velocity gain [1/s]", 0.0, 1.0e6),
    Param("input.max_age", 1.0, "reject joint states older than this relative to the newest [s]", 0.0, 3600.0),
    Param("input.max_future", 0.5, "reject joint states stamped this far ahead of the clock [s]", 0.0, 3600.0),
    Param("input.teleport_distance", 0.5, "a root jump larger than this between samples, and faster than "
          "input.teleport_speed, is a teleport: the body is re-placed, not swept [m]", 0.0, 100.0),
    # 10 m/s: a sprinter's top speed; a player stalled on a loaded host resumes its walk at 1-2 m/s
    Param("input.teleport_speed", 10.0, "a root jump larger than input.teleport_distance is a teleport only if "
          "faster than this over the time between its samples (a stalled sender resuming is motion) [m/s]",
          0.01, 1.0e6),
    # 300 rad/s, per joint channel: a BVH's Euler channels trade angle near gimbal lock, so real captures reach
    # ~210 rad/s on one channel after the loader's limit on rotation speed (tests/data/mocap_clips.yaml: the
    # fastest of the seven clips, benchmarks/clip_soak.py); capture glitches (a thigh flipping 175 deg in one
    # 120 Hz frame) are ~370 rad/s, and absurd velocities far beyond.
    Param("input.max_joint_speed", 300.0, "a joint state implying a joint faster than this since the last accepted one, "
          "or reporting a velocity above it, is rejected (joint_speed) [rad/s revolute, m/s prismatic]; rejected "
          "for longer than input.max_age, the stream restarts from the newest sample", 0.1, 1.0e6),
    # 0.1 m: above a sample's worth of motion of a fast limb (10 m/s over 1/120 s), below the jumps that tore
    # the jelly man after inputs stalled for 20-250 ms (tests/test_late_inputs.py)
    Param("input.max_late_jump", 0.1, "wall clock: a joint state arriving after physics stepped past the newest one "
          "(holding its pose) that moves a bone end further than this at the current time re-places the body on the "
          "new pose instead of yanking its flesh (counted as late_jumps) [m]", 0.0, 100.0),
    Param("input.max_root_distance", 1000.0, "a joint state placing the root (the prismatic joints) further than "
          "this from the world origin is rejected (root_range) [m]", 0.1, 1.0e7),
    Param("input.max_names", 1000, "a joint state with more names than this is rejected (too_many_names) before "
          "any per-name work", 1, 1000000),
    Param("input.joint_limit_margin", 0.05, "a revolute or prismatic joint's value is taken up to this fraction of "
          "its URDF range (upper - lower) beyond either limit; further out it is refused (joint_range) and the joint "
          "keeps its last value (continuous joints and revolute joints spanning a full turn are wrapped instead)",
          0.0, 1.0e6),
    Param("output.frame_id", "world", "frame of every published message"),
    Param("output.max_bone_distance", 0.3, "a state with a surface vertex farther than this from its bone (or 1.5 "
          "times its distance at rest, if larger) is diverged: never published or recorded, the body is reset [m]",
          0.01, 100.0),
    Param("output.marker_rate_hz", 30.0, "surface Marker rate (0 = off)", 0.0, 1000.0),
    Param("output.stress_rate_hz", 10.0, "stress PointCloud2 rate (0 = off)", 0.0, 1000.0),
    Param("output.diagnostics_rate_hz", 2.0, "DiagnosticArray rate (0 = off)", 0.0, 100.0),
    Param("output.colormap", "turbo", "colour map of the stress on the surface", choices=COLORMAPS),
    Param("output.stress_max", 0.0, "von Mises stress mapped to the top colour [Pa]; 0 = E / 20", 0.0, 1.0e12),
    Param("output.live_port", 0, "serve the topics live over the Foxglove WebSocket protocol on this port, the bytes "
          "published and recorded (8765 is Foxglove's default; 0 = off)", 0, 65535),
    Param("output.live_host", "127.0.0.1", "address the live view binds: 127.0.0.1 serves this host only, 0.0.0.0 "
          "every interface"),
    Param("recording.enabled", False, "record inputs and outputs to an MCAP bag"),
    Param("recording.dir", "bags", "folder for recordings (a timestamped bag folder is made inside)"),
    Param("recording.prefix", "clusterfem", "bag folder name prefix"),
    Param("recording.max_queue_mb", 64.0, "bytes of messages waiting for the bag's disk writer [MB]; beyond, messages "
          "are dropped from the recording and counted (recording_dropped), memory never grows", 1.0, 4096.0),
)
_BY_NAME = {p.name: p for p in PARAMS}


class ConfigError(ClusterFemError, ValueError):
    """A scene parameter with an invalid value; the message names it, the value and the valid range."""


FRAME_ID_MAX = 256
_FRAME_ID = re.compile(r"[A-Za-z_/][A-Za-z0-9_/]*")


def unknown_name_error(name: str) -> ConfigError:
    """The error for a parameter name that is not a scene parameter, naming the nearest known one."""
    close = difflib.get_close_matches(name, _BY_NAME, n=1, cutoff=0.6) or \
        [n for n in _BY_NAME if n.split(".")[-1] == name.split(".")[-1]]
    hint = f": did you mean {close[0]!r}?" if close else ": see config.PARAMS for the scene parameters"
    return ConfigError(f"unknown scene parameter {name!r}{hint}")


# YAML 1.1 (rcl's params-file and -p parser; PyYAML for yes/on/true) reads these unquoted words as booleans
_YAML_BOOL_WORDS = {True: ("y", "yes", "on", "true"), False: ("n", "no", "off", "false")}


def _text_value(p: Param, value: Any) -> str:
    """A text parameter's value: a choice in any case ('Y' or 'y' for an axis), or the choice a YAML 1.1
    boolean was spelt as (``fit_up: Y`` arrives as True); TypeError for anything else that is not text."""
    if isinstance(value, bool) and p.choices:
        spelt = [c for c in p.choices if c.lower() in _YAML_BOOL_WORDS[value]]
        if len(spelt) == 1:
            return spelt[0]
    if not isinstance(value, str):
        raise TypeError
    if p.choices and value not in p.choices:
        same = [c for c in p.choices if c.lower() == value.lower()]
        return same[0] if len(same) == 1 else value
    return value


def check_value(name: str, value: Any) -> Any:
    """Validate one scene parameter; returns the value coerced to the default's type."""
    if name not in _BY_NAME:
        raise unknown_name_error(name)
    return check_param(_BY_NAME[name], value)


def check_param(p: Param, value: Any) -> Any:
    """Validate a value of the parameter ``p`` (of any node's table: PARAMS, motion.PLAYER_TABLE); returns it
    coerced to the default's type: an integer for a float, a choice in any case or spelt as a YAML 1.1 boolean."""
    name, d = p.name, p.default
    if p.or_auto:                                    # 'auto' in any case, else checked as a float parameter
        if isinstance(value, str) and value.strip().lower() == AUTO:
            return AUTO
        d = float(p.lo)
    if p.length_unit:                                # a unit name or metres per unit, checked before the file is read
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            value = repr(float(value))
        try:
            parse_unit(value)
        except ValueError as exc:
            raise ConfigError(f"{name}: {exc}") from None
    try:
        if isinstance(d, bool):
            if not isinstance(value, bool):
                raise TypeError
        elif isinstance(d, int):
            if isinstance(value, bool) or int(value) != value:
                raise TypeError
            value = int(value)
        elif isinstance(d, float):
            if isinstance(value, bool):
                raise TypeError
            value = float(value)
        elif isinstance(d, list):
            if p.item in (str, bool):
                if isinstance(value, str) or not all(isinstance(x, p.item) for x in value):
                    raise TypeError
                value = list(value)
            else:
                if isinstance(value, str) or any(isinstance(x, (bool, str)) for x in value):
                    raise TypeError
                value = [float(x) for x in value]
        elif isinstance(d, str):
            value = _text_value(p, value)
    except (TypeError, ValueError):
        want = f"a list of {p.item.__name__}" if isinstance(d, list) else f"{type(d).__name__} like {d!r}"
        want = f"'auto' or {want}" if p.or_auto else want
        hint = (": YAML reads an unquoted y, yes, on, true (n, no, off, false) as a boolean; quote the value"
                if isinstance(d, str) and isinstance(value, bool) else "")
        raise ConfigError(f"{name} = {value!r}: expected {want}{hint}") from None
    if p.choices is not None and value not in p.choices:
        raise ConfigError(f"{name} = {value!r}: choose one of {', '.join(p.choices)}")
    if p.lo is not None and not (p.lo <= value <= p.hi):
        raise ConfigError(f"{name} = {value!r} is outside [{p.lo:g}, {p.hi:g}]: {p.description}")
    if isinstance(d, float) and value != value:
        raise ConfigError(f"{name} = nan: give a finite number")
    if isinstance(d, list) and p.item is float and not all(x - x == 0.0 for x in value):
        raise ConfigError(f"{name} = {value}: give finite numbers")
    if name == "output.frame_id" and not (len(value) <= FRAME_ID_MAX and _FRAME_ID.fullmatch(value)):
        shown = value if len(value) <= 40 else f"{value[:40]}... ({len(value)} characters)"
        raise ConfigError(f"{name} = {shown!r}: give a frame name of at most {FRAME_ID_MAX} letters, digits, '_' "
                          "and '/' (not starting with a digit), e.g. 'world'")
    return value


# Typed sections of the configuration: the parameters named <section>.<field>, as read by the code that uses
# them (SceneConfig.material, .physics, ...); the parameters outside any section (method, warping, warping_model)
# are attributes of SceneConfig. Their fields have no defaults: the one set of defaults, ranges and descriptions
# is PARAMS (tests/test_config_sections.py checks that every parameter is a field or an attribute).

@dataclass(frozen=True)
class BodySection:
    kind: str                       # one of BODIES
    mesh_file: str
    target_tets: int
    surface_file: str
    surface_group: str
    surface_unit: str               # 'auto', a unit name or metres per unit of surface_file (parse_unit)
    bone_radius: float              # [m]
    flesh: str                      # 'auto' (radii by bone role) or 'uniform' (body.bone_radius)
    cover_thickness: float          # [m]
    cover_shapes: str               # 'collision' or 'visual'
    cover_max_triangles: int        # skeleton/urdf_check.MAX_TRIANGLES
    scale: float
    fix_bottom: bool
    min_tet_quality: float          # fem/mesh/tet_quality.py
    skin: str                       # 'smooth' or 'voxel' (a jelly man's surface)


@dataclass(frozen=True)
class MaterialSection:
    young_modulus: float            # E [Pa]
    poisson_ratio: float            # nu [-]
    density: float                  # rho [kg/m^3]
    mass_damping: float             # Rayleigh xi [1/s]
    stiffness_damping: float        # Rayleigh zeta [s]
    volume_stiffness: float         # kappa: the whole volume's pressure, a multiple of the bulk modulus


@dataclass(frozen=True)
class PhysicsSection:
    step: float                     # h [s]
    timer_hz: float
    safety: float
    mass_scaling: float             # the largest share of the body's mass added for the step (fem/mass_scaling.py)
    plan_stretch: bool              # explicit warped steps planned for the stretch (fem/materials/stretch.py)
    allow_unbounded_warping: bool   # warping_model 'vertex' accepted (fem/materials/warping_models.py)
    max_substeps: int
    clock: str                      # 'wall' or 'input'
    input_wait: float               # wall clock: the longest lag behind the clock waiting for late inputs [s]
    max_catchup_steps: int
    gravity: float                  # along world z [m/s^2]


@dataclass(frozen=True)
class ModalSection:
    k: int                          # modes of method 'modal'


@dataclass(frozen=True)
class BudgetSection:
    max_error_mm: float             # 0: off
    measured_points: str            # '': the shipped points


@dataclass(frozen=True)
class SkeletonSection:
    source: str                     # one of SKELETONS
    urdf_file: str
    up_axis: str
    root_joint: str
    bind_pose: str                  # 'neutral', 'first_frame' or 'auto'
    bind_bvh: str
    bvh_unit: str                   # 'auto', a unit name or metres per unit (skeleton/bvh_placement.py)
    bvh_up: str                     # 'auto' or a signed file axis
    bind_joints: list
    bind_angles: list
    fit: str
    fit_up: str
    fit_forward: str
    fit_offset: list                # x, y, z [m]
    fit_tolerance: float
    max_urdf_bytes: int             # the URDF check's limits (skeleton/urdf_check.py)
    max_links: int
    max_joints: int
    max_depth: int
    max_meshes: int


@dataclass(frozen=True)
class BindingSection:
    level_radii: list
    relative_levels: bool
    skip_bones: list
    kp: list
    kd: list
    kinematic_core: bool
    sliding_levels: int
    crush_release: float


@dataclass(frozen=True)
class AnchorsSection:
    points: list                    # x, y, z, ... [m]
    bones: list
    sliding: list
    radius: float
    kp: float
    kd: float


@dataclass(frozen=True)
class InputSection:
    max_age: float
    max_future: float
    teleport_distance: float
    teleport_speed: float
    max_joint_speed: float
    max_late_jump: float
    max_root_distance: float
    max_names: int
    joint_limit_margin: float       # fraction of a joint's URDF range (skeleton/joint_limits.py)


@dataclass(frozen=True)
class OutputSection:
    frame_id: str
    max_bone_distance: float        # [m]
    marker_rate_hz: float           # 0: off
    stress_rate_hz: float
    diagnostics_rate_hz: float
    colormap: str
    stress_max: float               # [Pa], 0: E / 20
    live_port: int                  # Foxglove WebSocket live view, 0: off
    live_host: str


@dataclass(frozen=True)
class RecordingSection:
    enabled: bool
    dir: str
    prefix: str
    max_queue_mb: float


SECTIONS = {"body": BodySection, "material": MaterialSection, "modal": ModalSection, "physics": PhysicsSection,
            "budget": BudgetSection, "skeleton": SkeletonSection, "binding": BindingSection,
            "anchors": AnchorsSection, "input": InputSection, "output": OutputSection,
            "recording": RecordingSection}


@dataclass(frozen=True)
class SceneConfig:
    values: dict = field(default_factory=lambda: {p.name: p.default for p in PARAMS})

    def __getitem__(self, name: str) -> Any:
        return self.values[name]

    def section(self, name: str):
        """The parameters ``<name>.*`` as the typed section SECTIONS[name]."""
        cls = SECTIONS[name]
        return cls(**{f.name: self.values[f"{name}.{f.name}"] for f in fields(cls)})

    # The parameters outside any section, already typed by check_value.
    @property
    def method(self) -> str:
        """The integrator, one of METHODS."""
        return self.values["method"]

    @property
    def warping(self) -> bool:
        return self.values["warping"]

    @property
    def warping_model(self) -> str:
        """One of WARPING_MODELS: the parameter, with 'auto' resolved (fem/materials/warping_models.auto_model)."""
        name = self.values["warping_model"]
        if name != AUTO:
            return name
        return auto_model(self.method, self.values["budget.max_error_mm"] > 0, self.values["physics.plan_stretch"])

    @property
    def marker_stress_max(self) -> float:
        """The von Mises stress [Pa] the node's surface Markers colour at the top of the map: output.stress_max,
        or E / 20 when that is 0. The one definition: the node colours by it, a renderer reads recorded colours
        back with it."""
        return self.output.stress_max or self.material.young_modulus / 20.0

    # Each typed section is built once per config (a config is never changed, with_values makes a new one):
    # the physics thread and the joint-state callback read them per step and per message.
    @cached_property
    def body(self) -> BodySection:
        return self.section("body")

    @property
    def volume_stiffness(self) -> float:
        """kappa of the whole volume's pressure: the parameter, with 'auto' resolved by the body kind
        (body_kinds.BodyDeclaration.volume_stiffness)."""
        kappa = self.values["material.volume_stiffness"]
        return BODY_DECLARATIONS[self.values["body.kind"]].volume_stiffness if kappa == AUTO else kappa

    @cached_property
    def material(self) -> MaterialSection:
        return replace(self.section("material"), volume_stiffness=self.volume_stiffness)

    @cached_property
    def modal(self) -> ModalSection:
        return self.section("modal")

    @cached_property
    def physics(self) -> PhysicsSection:
        return self.section("physics")

    @cached_property
    def budget(self) -> BudgetSection:
        return self.section("budget")

    @cached_property
    def skeleton(self) -> SkeletonSection:
        return self.section("skeleton")

    @cached_property
    def binding(self) -> BindingSection:
        return self.section("binding")

    @cached_property
    def anchors(self) -> AnchorsSection:
        return self.section("anchors")

    @cached_property
    def input(self) -> InputSection:
        return self.section("input")

    @cached_property
    def output(self) -> OutputSection:
        return self.section("output")

    @cached_property
    def recording(self) -> RecordingSection:
        return self.section("recording")

    def resolved(self) -> "SceneConfig":
        """A copy with ``warping_model`` and ``material.volume_stiffness`` 'auto' replaced by what they run: what a
        recording keeps, so that its replay runs the same model whatever the defaults become."""
        return self.with_values({"material.volume_stiffness": self.volume_stiffness}, warping_model=self.warping_model)

    def with_values(self, values: dict[str, Any] | None = None, **overrides: Any) -> "SceneConfig":
        """A copy with parameters replaced, from a {name: value} mapping and/or keywords that use '__'
        for '.' (body__kind='sphere')."""
        return from_mapping({**self.values, **(values or {}),
                             **{k.replace("__", "."): v for k, v in overrides.items()}})


def from_mapping(values: dict[str, Any]) -> SceneConfig:
    """Validate a flat {name: value} mapping (missing names take their defaults) and cross-check it."""
    out = {p.name: p.default for p in PARAMS}
    for name, value in values.items():
        out[name] = check_value(name, value)
    radii, kp, kd = out["binding.level_radii"], out["binding.kp"], out["binding.kd"]
    if not radii or any(b <= a for a, b in zip(radii, radii[1:])) or radii[0] <= 0:
        raise ConfigError(f"binding.level_radii = {radii}: give positive, strictly increasing radii in metres")
    if not (len(kp) == len(kd) == len(radii)):
        raise ConfigError(f"binding.kp ({len(kp)} values) and binding.kd ({len(kd)}) need one value per level "
                          f"of binding.level_radii ({len(radii)})")
    sliding = out["binding.sliding_levels"]
    if sliding > len(radii):
        raise ConfigError(f"binding.sliding_levels = {sliding}: there are only {len(radii)} levels "
                          f"(binding.level_radii); give 0..{len(radii)}")
    if sliding == len(radii) and out["binding.kinematic_core"]:
        raise ConfigError(f"binding.sliding_levels = {sliding} lets the innermost level slide, but "
                          "binding.kinematic_core prescribes it: slide fewer levels or turn the kinematic core off")
    points, bones = out["anchors.points"], out["anchors.bones"]
    if len(points) % 3:
        raise ConfigError(f"anchors.points has {len(points)} numbers: give x, y, z per anchor point")
    if bones and len(bones) != len(points) // 3:
        raise ConfigError(f"anchors.bones has {len(bones)} names for {len(points) // 3} anchor points: give one per "
                          "point ('' for a point fixed in the world), or none")
    sliding = out["anchors.sliding"]
    if sliding and len(sliding) != len(points) // 3:
        raise ConfigError(f"anchors.sliding has {len(sliding)} values for {len(points) // 3} anchor points: give one "
                          "per point (true: slides along its bone), or none")
    for k, slides in enumerate(sliding):
        if slides and not (bones and bones[k]):
            raise ConfigError(f"anchors.sliding[{k}] is true but anchor point {k} has no bone (anchors.bones): a point "
                              "slides along a bone's axis; name its bone in anchors.bones or set sliding to false")
    if any(bones) and out["skeleton.source"] == "none":
        raise ConfigError(f"anchors.bones = {bones} names bones, but skeleton.source is 'none': give '' (fixed in the "
                          "world) or choose a skeleton")
    body_refusal = check_body_choice(out)
    if body_refusal:
        raise ConfigError(body_refusal)
    if out["skeleton.source"] == "urdf_file" and not out["skeleton.urdf_file"]:
        raise ConfigError("skeleton.source = 'urdf_file' needs skeleton.urdf_file: the path of a URDF")
    if out["binding.relative_levels"]:
        if radii[-1] > 1.0:
            raise ConfigError(f"binding.level_radii = {radii} with binding.relative_levels: give fractions of the "
                              "flesh thickness in (0, 1], e.g. [0.35, 0.6]")
    if len(out["skeleton.bind_joints"]) != len(out["skeleton.bind_angles"]):
        raise ConfigError(f"skeleton.bind_joints has {len(out['skeleton.bind_joints'])} names and "
                          f"skeleton.bind_angles {len(out['skeleton.bind_angles'])} values: give one angle per joint")
    if len(out["skeleton.fit_offset"]) != 3:
        raise ConfigError(f"skeleton.fit_offset = {out['skeleton.fit_offset']}: give x, y, z [m]")
    if "auto" != out["skeleton.fit_up"].lstrip("-") == out["skeleton.fit_forward"].lstrip("-"):
        raise ConfigError(f"skeleton.fit_up = {out['skeleton.fit_up']!r} and skeleton.fit_forward = "
                          f"{out['skeleton.fit_forward']!r} lie along one axis: give two different axes")
    check_material_choice(out)
    return SceneConfig(out)


def check_body_choice(out: dict[str, Any]) -> str | None:
    """Why the flat scene mapping ``out`` cannot build its body.kind (its file missing, a skeleton it needs, relative
    binding levels it cannot give), by its declaration (body_kinds.BodyDeclaration), or None."""
    kind = out["body.kind"]
    d = BODY_DECLARATIONS[kind]
    if d.file_param and not out[d.file_param]:
        return f"body.kind = {kind!r} needs {d.file_param}: {d.file_what or 'the path of its file'}"
    if d.needs_skeleton and out["skeleton.source"] == "none":
        return f"body.kind = {kind!r} is built around a skeleton: set skeleton.source"
    if out["binding.relative_levels"] and not d.flesh_depth:
        deep = ", ".join(repr(n) for n, b in BODY_DECLARATIONS.items() if b.flesh_depth)
        return (f"binding.relative_levels is true but body.kind = {kind!r}: relative levels need a surface body, "
                f"one that knows its flesh depth (body.kind {deep}); give level_radii in metres instead")
    return None


def check_material_choice(out: dict[str, Any]) -> None:
    """Refuse the warping model a scene runs ('auto' resolved) where its declaration's flags say so
    (fem/materials/warping_models.MaterialDeclaration), with the refusal the integrators give."""
    name, method = SceneConfig(out).warping_model, out["method"]
    d = declared(name)
    if not out["warping"] or d is None:
        return
    if not d.bounded and method != "modal" and not out[ACKNOWLEDGEMENT]:
        raise ConfigError(unbounded_refusal(name))
    if d.clustered_only and method != "clustered":
        raise ConfigError(explicit_only_refusal(name, method))
    if method in ("clustered", "standard_explicit") and unacknowledged_undamped(
            name, True, out["material.mass_damping"], out["material.stiffness_damping"], out[ACKNOWLEDGEMENT]):
        raise ConfigError(undamped_corotation_refusal(method, name))
    if d.needs_stretch_plan and not out["physics.plan_stretch"]:
        raise ConfigError(stretch_plan_refusal(name))


def _flatten(d: dict, prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        name = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(_flatten(v, name + "."))
        else:
            out[name] = v
    return out


# A recording's scene file (SceneConfig.resolved) holds every parameter the node had when it recorded; these came
# later, or turned 'auto' later, and a recording without them ran these values (the replay reads them so).
RECORDED_BEFORE = {"material.volume_stiffness": 0.0}


def load_scene_file(path: str | Path, node_name: str = NODE_NAME, absent: dict[str, Any] | None = None) -> SceneConfig:
    """Read a ROS 2 parameter YAML (``<node>: ros__parameters: ...``, nested or dotted keys); ``absent``: values
    for names the file does not hold, instead of their defaults (RECORDED_BEFORE for a recording's file)."""
    path = Path(path)
    try:
        doc = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError(f"cannot read scene file {str(path)!r}: {exc}") from exc
    if not isinstance(doc, dict):
        raise ConfigError(f"scene file {str(path)!r} holds a {type(doc).__name__}, not a mapping: write "
                          f"'{node_name}:' / '  ros__parameters:' / '    name: value'")
    section = doc.get(node_name) or doc.get("/**") or {}
    params = section.get("ros__parameters") if isinstance(section, dict) else None
    if not isinstance(params, dict):
        raise ConfigError(f"{str(path)!r} has no '{node_name}: ros__parameters:' mapping of parameters")
    try:
        return from_mapping({**(absent or {}), **_flatten(params)})
    except ConfigError as exc:
        raise ConfigError(f"{str(path)!r}: {exc}") from None


def scene_file_text(config: SceneConfig, node_name: str = NODE_NAME) -> str:
    """The config as a ROS 2 parameter YAML that ``load_scene_file`` (and ``--params-file``) reads back."""
    nested: dict[str, Any] = {}
    for name, value in config.values.items():
        *path, leaf = name.split(".")
        d = nested
        for part in path:
            d = d.setdefault(part, {})
        d[leaf] = list(value) if isinstance(value, tuple) else value
    return yaml.safe_dump({node_name: {"ros__parameters": nested}}, sort_keys=False)


def default_scene_path() -> Path:
    """config/default_scene.yaml from the source tree, or from share/ when installed: through the ament index
    (colcon), else under the environment's prefix (where ``pip install`` puts setup.py's data_files)."""
    here = Path(__file__).resolve().parent.parent / "config" / "default_scene.yaml"
    if here.exists():
        return here
    try:
        from ament_index_python.packages import get_package_share_directory
        return Path(get_package_share_directory("clusterfem_ros")) / "config" / "default_scene.yaml"
    except Exception:  # not installed through ament: a pip install
        pip_share = Path(sys.prefix) / "share" / "clusterfem_ros" / "config" / "default_scene.yaml"
        return pip_share if pip_share.exists() else here
