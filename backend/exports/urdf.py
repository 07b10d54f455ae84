"""The rig as a URDF: one ``<link>`` per frame, one fixed ``<joint>`` per non-root frame.

Layout (what ``robot_state_publisher`` and ``urdfdom`` read; no inertia, visuals or collisions)::

    <?xml version="1.0" encoding="utf-8"?>
    <robot name="demo">
      <link name="base_link"/>
      <link name="lidar_top"/>
      <joint name="lidar_top_joint" type="fixed">
        <!-- 1-sigma: trans_m [...], rot_deg [...] (about the child's x, y, z) -->
        <parent link="base_link"/>
        <child link="lidar_top"/>
        <origin xyz="0.1 0.0 1.2" rpy="0.0 0.0 0.0"/>
      </joint>
    </robot>

Each joint's ``origin`` is ``T_parent_child`` of ``../shared/conventions.md`` (maps points in the child link
into the parent link): ``xyz`` in metres, ``rpy`` the fixed-axis roll, pitch, yaw in radians of URDF, so
``R = Rz(yaw) Ry(pitch) Rx(roll)``: the same angles as ROS's yaw/pitch/roll order (``urdf_model/pose.h``
``Rotation::setFromRPY``). Links and joints are listed parents first; a joint is named after its child with
``_joint``. The frames are those of :func:`~backend.exports.frame_tree.export_frames` in the chosen
convention. Floats are written at full precision (Python ``repr``, which ``urdfdom``'s locale-independent
``strToDouble`` reads back exactly); a NaN or infinity is refused (:class:`InputError` naming the frame).
URDF has no field for an uncertainty: the 1-sigma values ride in a comment of the joint.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np

from backend.core.finite import require_finite
from backend.core.rig import Rig
from backend.core.transforms import to_xyz_ypr
from backend.exports.formats import Convention
from backend.exports.frame_tree import ExportedFrame, export_frames
from backend.exports.yaml_fields import floats

JOINT_SUFFIX = "_joint"
"""A joint's name is its child link's name and this."""


def dump_urdf(rig: Rig, robot_name: str, convention: Convention = "optical") -> str:
    """URDF text of ``rig`` as a ``<robot name=robot_name>``, its frames in ``convention``."""
    frames = export_frames(rig, convention)
    robot = ET.Element("robot", name=robot_name)
    ET.SubElement(robot, "link", name=rig.root)
    for frame in frames:
        ET.SubElement(robot, "link", name=frame.child)
        robot.append(_joint(frame))
    ET.indent(robot)
    return '<?xml version="1.0" encoding="utf-8"?>\n' + ET.tostring(robot, encoding="unicode") + "\n"


def _joint(frame: ExportedFrame) -> ET.Element:
    """The fixed joint placing ``frame.child`` in ``frame.parent``."""
    require_finite({"T_parent_child": frame.T_parent_child, "sigma": frame.sigmas}, f"URDF: frame {frame.child!r}",
                   frame.sensor)
    xyz_m, (yaw, pitch, roll) = to_xyz_ypr(frame.T_parent_child)
    joint = ET.Element("joint", name=frame.child + JOINT_SUFFIX, type="fixed")
    if frame.sigmas is not None:
        trans_m, rot_deg = (floats(v) for v in frame.sigmas)
        joint.append(ET.Comment(f" 1-sigma: trans_m {trans_m}, rot_deg {rot_deg} (about the child's x, y, z) "))
    ET.SubElement(joint, "parent", link=frame.parent)
    ET.SubElement(joint, "child", link=frame.child)
    ET.SubElement(joint, "origin", xyz=_numbers(xyz_m), rpy=_numbers([roll, pitch, yaw]))
    return joint


def _numbers(values: np.ndarray | list[float]) -> str:
    """Space-separated full-precision floats, as URDF attributes hold vectors."""
    return " ".join(repr(v) for v in floats(values))
