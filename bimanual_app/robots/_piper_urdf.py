"""Writes the project's AgileX Piper URDF (``piper/piper.urdf``) from the reference kinematics.

The shipped URDF is this function's output (a test checks they are identical); change the geometry
here and regenerate with::

    .venv/bin/python -m bimanual_app.robots._piper_urdf > bimanual_app/robots/piper/piper.urdf

Joint chain: exactly the table in shared/reference/piper-kinematics.md. Collision shapes: capsules (a
cylinder plus two end spheres, because URDF has no capsule element and Pinocchio's parser rejects the
PyBullet extension), cylinders and boxes sized from the real arm's proportions (upper arm 70 mm thick,
forearm and wrist 56-64 mm, gripper palm 50 x 110 x 80 mm, fingers 20 x 50 x 10 mm). Visuals are the same
primitives. Inertials: solid cylinders / boxes of plausible masses (about 4.2 kg in all), not measured.
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = ["piper_urdf_text", "PIPER_TCP_OFFSET"]

# Fingertips (and the contract's gripper frame g) lie this far along the flange z axis (reference table).
PIPER_TCP_OFFSET = 0.1358

_VELOCITY = 3.0  # rad/s, piper_sdk MotorMaxSpdSet default (see _registry.py)
_EFFORT = {"joint1": 100, "joint2": 100, "joint3": 100, "joint4": 30, "joint5": 30, "joint6": 30}

# (name, type, parent, child, origin xyz, origin rpy, axis, (lower, upper)) -- the reference table
_JOINTS = [
    ("joint1", "revolute", "base_link", "link1", (0, 0, 0.123), (0, 0, 0), (0, 0, 1), (-2.618, 2.618)),
    ("joint2", "revolute", "link1", "link2", (0, 0, 0), (1.5708, -0.1359, -3.1416), (0, 0, 1), (0, 3.14)),
    ("joint3", "revolute", "link2", "link3", (0.28503, 0, 0), (0, 0, -1.7939), (0, 0, 1), (-2.967, 0)),
    ("joint4", "revolute", "link3", "link4", (-0.021984, -0.25075, 0), (1.5708, 0, 0), (0, 0, 1), (-1.745, 1.745)),
    ("joint5", "revolute", "link4", "link5", (0, 0, 0), (-1.5708, 0, 0), (0, 0, 1), (-1.22, 1.22)),
    ("joint6", "revolute", "link5", "link6", (8.8259e-5, -0.091, 0), (1.5708, 0, 0), (0, 0, 1), (-2.0944, 2.0944)),
    ("gripper_base_joint", "fixed", "link6", "gripper_base", (0, 0, 0), (0, 0, 0), None, None),
    ("joint7", "prismatic", "gripper_base", "link7", (0, 0, 0.1358), (1.5708, 0, 0), (0, 0, 1), (0, 0.035)),
    ("joint8", "prismatic", "gripper_base", "link8", (0, 0, 0.1358), (1.5708, 0, -3.1416), (0, 0, -1), (-0.035, 0)),
    ("gripper_tcp_joint", "fixed", "gripper_base", "gripper_tcp", (0, 0, PIPER_TCP_OFFSET), (0, 0, 0), None, None),
]


def _fmt(values) -> str:
    return " ".join(f"{float(v) + 0.0:.6g}" for v in values)


def _rpy_z_to(direction) -> np.ndarray:
    """URDF rpy of a frame whose z axis points along ``direction`` (3,)."""
    d = np.asarray(direction, dtype=float)
    d = d / np.linalg.norm(d)
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(z, d)
    s, c = np.linalg.norm(v), float(z @ d)
    if s < 1e-12:
        return np.zeros(3) if c > 0 else np.array([np.pi, 0.0, 0.0])
    with warnings.catch_warnings():  # gimbal lock for axes along x/y is harmless here
        warnings.simplefilter("ignore")
        return Rotation.from_rotvec(v / s * np.arctan2(s, c)).as_euler("xyz")


def _capsule(a, b, r):
    """A capsule from point ``a`` to ``b`` (link frame) of radius ``r``: cylinder + two end spheres."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return [
        ("cylinder", (a + b) / 2, _rpy_z_to(b - a), (r, np.linalg.norm(b - a))),
        ("sphere", a, (0, 0, 0), (r,)),
        ("sphere", b, (0, 0, 0), (r,)),
    ]


def _shape_xml(tag: str, shapes, material: str) -> list[str]:
    out = []
    for kind, xyz, rpy, dims in shapes:
        if kind == "cylinder":
            geom = f'<cylinder radius="{dims[0]:.6g}" length="{dims[1]:.6g}"/>'
        elif kind == "sphere":
            geom = f'<sphere radius="{dims[0]:.6g}"/>'
        else:
            geom = f'<box size="{_fmt(dims)}"/>'
        mat = f'\n      <material name="{material}"/>' if tag == "visual" else ""
        out.append(
            f'    <{tag}>\n      <origin xyz="{_fmt(xyz)}" rpy="{_fmt(rpy)}"/>\n'
            f"      <geometry>{geom}</geometry>{mat}\n    </{tag}>"
        )
    return out


def _inertial_cylinder(mass, a, b, r) -> str:
    """Solid cylinder of radius ``r`` spanning ``a`` to ``b`` (plus the caps' length)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    length = np.linalg.norm(b - a) + 2 * r
    transverse = mass * (3 * r * r + length * length) / 12
    axial = mass * r * r / 2
    rpy = _rpy_z_to(b - a) if np.linalg.norm(b - a) > 1e-9 else np.zeros(3)
    return _inertial_xml(mass, (a + b) / 2, rpy, (transverse, transverse, axial))


def _inertial_box(mass, center, size) -> str:
    x, y, z = size
    diag = (mass / 12 * (y * y + z * z), mass / 12 * (x * x + z * z), mass / 12 * (x * x + y * y))
    return _inertial_xml(mass, center, (0, 0, 0), diag)


def _inertial_xml(mass, com, rpy, diag) -> str:
    return (
        f'    <inertial>\n      <origin xyz="{_fmt(com)}" rpy="{_fmt(rpy)}"/>\n      <mass value="{mass:.6g}"/>\n'
        f'      <inertia ixx="{diag[0]:.6g}" ixy="0" ixz="0" iyy="{diag[1]:.6g}" iyz="0" izz="{diag[2]:.6g}"/>\n'
        "    </inertial>"
    )


def _links() -> dict:
    """link name -> (inertial xml, shapes, material) or None for a pure frame."""
    links: dict = {}
    # Every moving-arm shape is a capsule or a sphere (their bounding capsule is exact, so the collision
    # broad phase decides alone); only the gripper palm and fingers are boxes.
    links["base_link"] = (  # rounded base, top at z = 0.07 (its lower half is under the mounting surface)
        _inertial_cylinder(0.9, (0, 0, 0), (0, 0, 0.015), 0.055),
        _capsule((0, 0, 0), (0, 0, 0.015), 0.055),
        "dark",
    )
    links["link1"] = (  # shoulder housing, base frame z 0.06 .. 0.15
        _inertial_cylinder(0.6, (0, 0, -0.0165), (0, 0, -0.0165), 0.045),
        [("sphere", (0, 0, -0.0165), (0, 0, 0), (0.045,))],
        "grey",
    )
    links["link2"] = (  # upper arm: shoulder to elbow
        _inertial_cylinder(1.0, (0, 0, 0), (0.28503, 0, 0), 0.035),
        _capsule((0, 0, 0), (0.28503, 0, 0), 0.035),
        "grey",
    )
    to_wrist = np.array([-0.021984, -0.25075, 0.0])
    fore_end = to_wrist / np.linalg.norm(to_wrist) * 0.20  # stops short of the wrist (link4's sphere)
    links["link3"] = (
        _inertial_cylinder(0.6, (0, 0, 0), fore_end, 0.028),
        _capsule((0, 0, 0), fore_end, 0.028),
        "grey",
    )
    links["link4"] = (  # wrist housing around the joint-5 axis
        _inertial_cylinder(0.25, (0, 0, 0), (0, 0, 0), 0.032),
        [("sphere", (0, 0, 0), (0, 0, 0), (0.032,))],
        "dark",
    )
    a5, b5 = (0, -0.035, 0), (0, -0.068, 0)
    links["link5"] = (_inertial_cylinder(0.25, a5, b5, 0.028), _capsule(a5, b5, 0.028), "grey")
    links["link6"] = (  # flange
        _inertial_cylinder(0.1, (0, 0, -0.01), (0, 0, -0.01), 0.03),
        [("sphere", (0, 0, -0.01), (0, 0, 0), (0.03,))],
        "dark",
    )
    palm = (0.05, 0.11, 0.08)
    links["gripper_base"] = (
        _inertial_box(0.4, (0, 0, 0.045), palm),
        [("box", (0, 0, 0.045), (0, 0, 0), palm)],
        "dark",
    )
    # Finger box in the finger frame: x width, y along the approach (tip at y = 0, i.e. 0.1358 beyond the
    # flange), z along the finger's stroke; the inner face sits 1 mm from the centre line so the two
    # fingers never touch (they only move apart), z 0.001 .. 0.011.
    finger = (0.02, 0.05, 0.01)
    for name in ("link7", "link8"):
        links[name] = (
            _inertial_box(0.05, (0, -0.025, 0.006), finger),
            [("box", (0, -0.025, 0.006), (0, 0, 0), finger)],
            "grey",
        )
    links["gripper_tcp"] = None
    return links


def piper_urdf_text() -> str:
    """The Piper URDF as a string (deterministic)."""
    out = [
        '<?xml version="1.0"?>',
        "<!-- AgileX Piper, written by the Bi-JCR project from shared/reference/piper-kinematics.md",
        "     (generated by bimanual_app/robots/_piper_urdf.py; see docs/robots.md). Joint chain exactly as the",
        "     reference table. Collision and visual geometry are simple primitives (a capsule is a cylinder plus",
        "     two end spheres, since URDF has no capsule); inertials are plausible estimates (solid cylinders /",
        "     boxes, arm about 4.2 kg), not measured values. No mesh files. Frame gripper_tcp is the contract's",
        "     gripper frame g: origin midway between the closed fingertips, z = approach, y = closing direction,",
        "     x = y cross z. -->",
        '<robot name="piper">',
        '  <material name="grey"><color rgba="0.75 0.75 0.78 1"/></material>',
        '  <material name="dark"><color rgba="0.2 0.2 0.22 1"/></material>',
    ]
    for name, spec in _links().items():
        if spec is None:
            out.append(
                f'  <link name="{name}">\n'
                "    <!-- a frame only; a tiny inertial so simulators do not invent a 1 kg body -->\n"
                '    <inertial>\n      <mass value="0.001"/>\n'
                '      <inertia ixx="1e-07" ixy="0" ixz="0" iyy="1e-07" iyz="0" izz="1e-07"/>\n'
                "    </inertial>\n  </link>"
            )
            continue
        inertial, shapes, material = spec
        out.append(f'  <link name="{name}">')
        out.append(inertial)
        out += _shape_xml("visual", shapes, material)
        out += _shape_xml("collision", shapes, material)
        out.append("  </link>")
    for name, typ, parent, child, xyz, rpy, axis, limits in _JOINTS:
        out += [
            f'  <joint name="{name}" type="{typ}">',
            f'    <parent link="{parent}"/>',
            f'    <child link="{child}"/>',
            f'    <origin xyz="{_fmt(xyz)}" rpy="{_fmt(rpy)}"/>',
        ]
        if axis is not None:
            out.append(f'    <axis xyz="{_fmt(axis)}"/>')
            if typ == "revolute":
                out.append(
                    f'    <limit lower="{limits[0]}" upper="{limits[1]}" effort="{_EFFORT[name]}" velocity="{_VELOCITY}"/>'
                )
            else:
                out.append(f'    <limit lower="{limits[0]}" upper="{limits[1]}" effort="10" velocity="0.1"/>')
        out.append("  </joint>")
    out.append("</robot>")
    return "\n".join(out) + "\n"


if __name__ == "__main__":
    import sys

    sys.stdout.write(piper_urdf_text())
