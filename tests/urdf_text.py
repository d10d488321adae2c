"""URDF texts the URDF tests write: a small Y-up (ISB convention) humanoid on a fixed base whose leaf links
carry box, cylinder and sphere collision shapes. Our own text, kept small."""

HAND_BOX = (0.04, 0.16, 0.08)           # m, the hands' box (ISB axes: x forward, y up, z right)
FOOT_CYLINDER = (0.04, 0.22)            # m, radius and length of the feet's cylinder (turned to point forward)
HEAD_SPHERE = 0.09                      # m


def _link(name: str, mass: float = 2.0, shape: str = "") -> str:
    return (f'<link name="{name}"><inertial><mass value="{mass}"/><inertia ixx="0.01" iyy="0.01" izz="0.01" '
            f'ixy="0" ixz="0" iyz="0"/></inertial>{shape}</link>')


def _joint(name: str, parent: str, child: str, xyz: str, axis: str = "0 0 1") -> str:
    return (f'<joint name="{name}" type="revolute"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="{xyz}" rpy="0 0 0"/><axis xyz="{axis}"/>'
            f'<limit lower="-3" upper="3" effort="100" velocity="10"/></joint>')


def y_up_humanoid() -> str:
    """Standing along +Y at q = 0, facing +X, left side at -Z; pelvis at the origin, no root joint."""
    box = (f'<collision><origin xyz="0 -0.08 0" rpy="0 0 0"/><geometry><box size="{HAND_BOX[0]} {HAND_BOX[1]} '
           f'{HAND_BOX[2]}"/></geometry></collision>')
    cyl = (f'<collision><origin xyz="0.07 -0.04 0" rpy="0 1.5707963267948966 0"/><geometry><cylinder radius='
           f'"{FOOT_CYLINDER[0]}" length="{FOOT_CYLINDER[1]}"/></geometry></collision>')
    sphere = (f'<visual><geometry><box size="1 1 1"/></geometry></visual><collision><origin xyz="0 0.1 0"/>'
              f'<geometry><sphere radius="{HEAD_SPHERE}"/></geometry></collision>')
    parts = [_link("pelvis", 10.0), _link("chest", 10.0), _link("head", 4.0, sphere),
             _joint("spine", "pelvis", "chest", "0 0.25 0"), _joint("neck", "chest", "head", "0 0.25 0")]
    for side, z in (("left", -1.0), ("right", 1.0)):
        parts += [_link(f"{side}_clavicle", 1.0), _link(f"{side}_upper_arm"), _link(f"{side}_forearm"),
                  _link(f"{side}_hand", 0.5, box),
                  _link(f"{side}_thigh", 6.0), _link(f"{side}_shin", 3.0), _link(f"{side}_foot", 1.0, cyl),
                  _joint(f"{side}_clavicle", "chest", f"{side}_clavicle", "0 0.2 0", "1 0 0"),
                  _joint(f"{side}_shoulder", f"{side}_clavicle", f"{side}_upper_arm", f"0 0 {0.25 * z}"),
                  _joint(f"{side}_elbow", f"{side}_upper_arm", f"{side}_forearm", "0 -0.28 0"),
                  _joint(f"{side}_wrist", f"{side}_forearm", f"{side}_hand", "0 -0.25 0"),
                  _joint(f"{side}_hip", "pelvis", f"{side}_thigh", f"0 -0.05 {0.06 * z}"),
                  _joint(f"{side}_knee", f"{side}_thigh", f"{side}_shin", "0 -0.42 0"),
                  _joint(f"{side}_ankle", f"{side}_shin", f"{side}_foot", "0 -0.4 0")]
    return '<?xml version="1.0"?>\n<robot name="y_up_test_humanoid">\n  ' + "\n  ".join(parts) + "\n</robot>\n"
