"""Generates `ur5e.urdf` next to this file: `.venv/bin/python models/ur5e/make_urdf.py`.

The kinematics and limits come from `lrnbv_drake.core.robot.kinematics`, so the model and the
analytic IK cannot drift apart (`tests/test_kinematics.py` checks the shipped file is this
script's output).

- Frames and joint origins are those of the ROS2 `ur_description` (`urdf/ur_macro.xacro` with
  `config/ur5e/default_kinematics.yaml`), including the dummy `base_link_inertia` that carries
  the Rz(pi) between REP-103 `base_link` and the controller's frame, and the fixed frames `base`,
  `flange` and `tool0`.
- Masses, centres of mass and inertia tensors are UR's published values for the UR5e, in the
  URDF link frames as `config/ur5e/physical_parameters.yaml` gives them (the tensor frames carry
  the DH-frame rotation); the base is a 4 kg cylinder, as in ROS.
- Geometry is primitive cylinders sized to enclose the real arm: the base's 149 mm footprint,
  size-3 joint housings of 128 mm (base, shoulder) and 120 mm (elbow), tubes of 95 mm (upper
  arm) and 78 mm (forearm), size-1 wrist housings of 90 mm, the 63 mm ISO 9409-1-50-4-M6 tool
  flange. Collision and visual shapes are the same volumes, so the rendered ToF sensor sees what
  the collision checker checks; visuals add UR-blue joint caps carved out of the housing ends.
"""

from __future__ import annotations

import dataclasses as dc
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from lrnbv_drake.core.robot import kinematics as kin

PI = np.pi
DRAKE_NS = "http://drake.mit.edu"
OUT = Path(__file__).resolve().parent / "ur5e.urdf"
CAP_THICKNESS = 0.01

MATERIALS = {
    "ur_grey": (0.78, 0.80, 0.82, 1.0),
    "ur_silver": (0.88, 0.89, 0.90, 1.0),
    "ur_blue": (0.45, 0.66, 0.82, 1.0),
    "ur_dark": (0.25, 0.26, 0.28, 1.0),
}


@dc.dataclass(frozen=True)
class Cylinder:
    """A link-frame cylinder of `radius` along `axis`, from s0 to s1 along it, through `at`
    (whose coordinate along the axis is ignored)."""

    name: str
    radius: float
    axis: str
    s0: float
    s1: float
    material: str
    at: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # "s0" or "s1": the end that gets a blue cap in the visual.
    cap: str | None = None

    def span(self, s0: float, s1: float) -> tuple[float, list[float], tuple[float, float, float]]:
        """(length, centre xyz, rpy) of the part of this cylinder between s0 and s1."""
        k = "xyz".index(self.axis)
        centre = list(self.at)
        centre[k] = (s0 + s1) / 2
        rpy = {"x": (0.0, PI / 2, 0.0), "y": (PI / 2, 0.0, 0.0), "z": (0.0, 0.0, 0.0)}[self.axis]
        return abs(s1 - s0), centre, rpy


# Geometry in each URDF link frame (see the module docstring and the ROS frames): z is the
# joint axis of every moving link; the upper arm tube lies 0.138 m along joint 2's axis from
# the base axis and the forearm tube 0.007 m (ROS's shoulder_offset and elbow_offset).
GEOMETRY: dict[str, list[Cylinder]] = {
    "base_link_inertia": [
        Cylinder("base_foot", 0.0745, "z", 0.0, 0.03, "ur_dark"),
        Cylinder("base_housing", 0.064, "z", 0.03, 0.0925, "ur_grey"),
    ],
    "shoulder_link": [
        Cylinder("shoulder_pan_housing", 0.064, "z", -0.07, 0.0, "ur_grey"),
        # Joint 2's axis is -y here; the housing reaches from behind the base axis to the
        # upper arm's outer face.
        Cylinder("shoulder_lift_housing", 0.064, "y", -0.19, 0.065, "ur_grey", cap="s1"),
    ],
    "upper_arm_link": [
        Cylinder("upper_arm_tube", 0.0475, "x", kin.DH_A[1], 0.0, "ur_silver", at=(0, 0, 0.138)),
    ],
    "forearm_link": [
        Cylinder("elbow_housing", 0.06, "z", -0.04, 0.19, "ur_grey", cap="s0"),
        Cylinder("forearm_tube", 0.039, "x", kin.DH_A[2], 0.0, "ur_silver", at=(0, 0, 0.007)),
        Cylinder(
            "wrist_1_housing", 0.045, "z", -0.035, kin.DH_D[3], "ur_grey",
            at=(kin.DH_A[2], 0, 0), cap="s0",
        ),
    ],
    "wrist_1_link": [
        # Joint 5's axis is -y here, and meets joint 6's at y = -d5.
        Cylinder("wrist_2_housing", 0.045, "y", -kin.DH_D[4], 0.045, "ur_grey", cap="s1"),
    ],
    "wrist_2_link": [
        # Joint 6's axis is +y here; the flange face is at y = d6.
        Cylinder("wrist_3_housing", 0.045, "y", -0.045, kin.DH_D[5] - 0.016, "ur_grey", cap="s0"),
    ],
    "wrist_3_link": [
        Cylinder("flange_ring", 0.0375, "z", -0.016, -0.006, "ur_dark"),
        Cylinder("tool_flange", 0.0315, "z", -0.006, 0.0, "ur_silver"),
    ],
}

# (mass kg, centre of mass xyz, tensor frame rpy, ixx, ixy, ixz, iyy, iyz, izz) in link frames.
INERTIA = {
    "shoulder_link": (3.761, (0, -0.00193, -0.02561), (PI / 2, 0, 0),
                      0.00700210, 0.00000073, -0.00001053, 0.00648091, 0.00049994, 0.00657286),
    "upper_arm_link": (8.058, (-0.2125, 0, 0.11336), (0, 0, 0),
                       0.01505885, -0.00005400, 0.00000563, 0.33388086, -0.00000181, 0.33247207),
    "forearm_link": (2.846, (-0.2422, 0, 0.0265), (0, 0, 0),
                     0.00399632, -0.00001365, 0.00137272, 0.07879254, -0.00000660, 0.07848510),
    "wrist_1_link": (1.37, (0, -0.01634, -0.0018), (PI / 2, 0, 0),
                     0.00165491, -0.00000282, -0.00000438, 0.00135962, 0.00010157, 0.00126279),
    "wrist_2_link": (1.3, (0, 0.01634, -0.0018), (-PI / 2, 0, 0),
                     0.00135617, -0.00000274, 0.00000444, 0.00127827, -0.00005048, 0.00096614),
    "wrist_3_link": (0.365, (0, 0, -0.001159), (0, 0, 0),
                     0.00018694, 0.00000006, -0.00000017, 0.00018908, -0.00000092, 0.00025756),
}
BASE_MASS, BASE_RADIUS, BASE_LENGTH = 4.0, 0.06, 0.05

# (joint, parent, child, xyz, rpy): the moving joints in JOINT_NAMES order, from the DH table.
ARM_JOINTS = [
    ("shoulder_pan_joint", "base_link_inertia", "shoulder_link", (0, 0, kin.DH_D[0]), (0, 0, 0)),
    ("shoulder_lift_joint", "shoulder_link", "upper_arm_link", (0, 0, 0), (PI / 2, 0, 0)),
    ("elbow_joint", "upper_arm_link", "forearm_link", (kin.DH_A[1], 0, 0), (0, 0, 0)),
    ("wrist_1_joint", "forearm_link", "wrist_1_link", (kin.DH_A[2], 0, kin.DH_D[3]), (0, 0, 0)),
    ("wrist_2_joint", "wrist_1_link", "wrist_2_link", (0, -kin.DH_D[4], 0), (PI / 2, 0, 0)),
    ("wrist_3_joint", "wrist_2_link", "wrist_3_link", (0, kin.DH_D[5], 0), (PI / 2, PI, PI)),
]
FIXED_JOINTS = [
    ("base_link-base_link_inertia", "base_link", "base_link_inertia", (0, 0, PI)),
    ("base_link-base_fixed_joint", "base_link", "base", (0, 0, PI)),
    ("wrist_3-flange", "wrist_3_link", "flange", (0, -PI / 2, -PI / 2)),
    ("flange-tool0", "flange", "tool0", (PI / 2, 0, PI / 2)),
]


def _num(*values: float) -> str:
    """Shortest round-tripping decimal text for each value, space separated."""
    return " ".join(repr(float(v) + 0.0).removesuffix(".0") for v in values)


def _sub(parent: ET.Element, tag: str, **attrib: str) -> ET.Element:
    return ET.SubElement(parent, tag, attrib)


def _add_cylinder(parent: ET.Element, tag: str, name: str, cyl: Cylinder, s0: float,
                  s1: float, material: str | None) -> None:
    length, xyz, rpy = cyl.span(s0, s1)
    element = _sub(parent, tag, name=name)
    _sub(element, "origin", xyz=_num(*xyz), rpy=_num(*rpy))
    _sub(_sub(element, "geometry"), "cylinder", radius=_num(cyl.radius), length=_num(length))
    if material is not None:
        _sub(element, "material", name=material)


def _add_link(robot: ET.Element, name: str) -> None:
    link = _sub(robot, "link", name=name)
    if name == "base_link_inertia":
        izz = BASE_MASS * BASE_RADIUS**2 / 2
        ixx = BASE_MASS * (3 * BASE_RADIUS**2 + BASE_LENGTH**2) / 12
        inertial = _sub(link, "inertial")
        _sub(inertial, "origin", xyz="0 0 0", rpy="0 0 0")
        _sub(inertial, "mass", value=_num(BASE_MASS))
        _sub(inertial, "inertia", ixx=_num(ixx), ixy="0", ixz="0", iyy=_num(ixx), iyz="0",
             izz=_num(izz))
    elif name in INERTIA:
        mass, com, rpy, ixx, ixy, ixz, iyy, iyz, izz = INERTIA[name]
        inertial = _sub(link, "inertial")
        _sub(inertial, "origin", xyz=_num(*com), rpy=_num(*rpy))
        _sub(inertial, "mass", value=_num(mass))
        _sub(inertial, "inertia", ixx=_num(ixx), ixy=_num(ixy), ixz=_num(ixz), iyy=_num(iyy),
             iyz=_num(iyz), izz=_num(izz))
    for cyl in GEOMETRY.get(name, []):
        lo, hi = cyl.s0, cyl.s1
        if cyl.cap == "s0":
            _add_cylinder(link, "visual", f"{cyl.name}_cap", cyl, lo, lo + CAP_THICKNESS,
                          "ur_blue")
            _add_cylinder(link, "visual", cyl.name, cyl, lo + CAP_THICKNESS, hi, cyl.material)
        elif cyl.cap == "s1":
            _add_cylinder(link, "visual", cyl.name, cyl, lo, hi - CAP_THICKNESS, cyl.material)
            _add_cylinder(link, "visual", f"{cyl.name}_cap", cyl, hi - CAP_THICKNESS, hi,
                          "ur_blue")
        else:
            _add_cylinder(link, "visual", cyl.name, cyl, lo, hi, cyl.material)
        _add_cylinder(link, "collision", cyl.name, cyl, lo, hi, None)


def make_urdf() -> str:
    """The URDF text."""
    ET.register_namespace("drake", DRAKE_NS)
    robot = ET.Element("robot", name="ur5e")
    for name, rgba in MATERIALS.items():
        _sub(_sub(robot, "material", name=name), "color", rgba=_num(*rgba))
    links = ["base_link", "base_link_inertia"] + [j[2] for j in ARM_JOINTS]
    for name in [*links, "base", "flange", "tool0"]:
        _add_link(robot, name)
    for i, (name, parent, child, xyz, rpy) in enumerate(ARM_JOINTS):
        joint = _sub(robot, "joint", name=name, type="revolute")
        _sub(joint, "parent", link=parent)
        _sub(joint, "child", link=child)
        _sub(joint, "origin", xyz=_num(*xyz), rpy=_num(*rpy))
        _sub(joint, "axis", xyz="0 0 1")
        _sub(joint, "limit", lower=_num(kin.JOINT_LOWER[i]), upper=_num(kin.JOINT_UPPER[i]),
             effort=_num(kin.EFFORT_LIMIT[i]), velocity=_num(kin.VELOCITY_LIMIT[i]),
             **{f"{{{DRAKE_NS}}}acceleration": _num(kin.ACCELERATION_LIMIT[i])})
    for name, parent, child, rpy in FIXED_JOINTS:
        joint = _sub(robot, "joint", name=name, type="fixed")
        _sub(joint, "parent", link=parent)
        _sub(joint, "child", link=child)
        _sub(joint, "origin", xyz="0 0 0", rpy=_num(*rpy))
    # Transmissions make Drake create one actuator per joint, carrying the effort limit.
    for name, *_ in ARM_JOINTS:
        transmission = _sub(robot, "transmission", name=name.replace("_joint", "_trans"))
        _sub(transmission, "type").text = "transmission_interface/SimpleTransmission"
        _sub(transmission, "joint", name=name)
        actuator = _sub(transmission, "actuator", name=name.replace("_joint", "_motor"))
        _sub(actuator, "mechanicalReduction").text = "1"
    ET.indent(robot)
    header = (
        '<?xml version="1.0"?>\n'
        "<!-- UR5e with primitive geometry. Generated by make_urdf.py: edit that, not this. -->\n"
    )
    return header + ET.tostring(robot, encoding="unicode") + "\n"


if __name__ == "__main__":
    OUT.write_text(make_urdf())
    print(f"wrote {OUT}")
