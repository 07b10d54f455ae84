"""The rig as a ROS 2 Python launch file: one ``tf2_ros`` ``static_transform_publisher`` per frame.

The file defines ``generate_launch_description()`` returning a ``launch.LaunchDescription`` of one
``launch_ros.actions.Node(package="tf2_ros", executable="static_transform_publisher", name=...,
arguments=[...])`` per non-root frame, parents first (``ros2 launch rig.launch.py``)::

    Node(
        package="tf2_ros",
        executable="static_transform_publisher",
        name="static_tf_lidar_top",
        arguments=[
            "--x", "0.1", "--y", "0.0", "--z", "1.2",
            "--qx", "0.0", "--qy", "0.0", "--qz", "0.0", "--qw", "1.0",
            "--frame-id", "base_link", "--child-frame-id", "lidar_top",
        ],
    ),

The arguments are the new-style flags of ros2/geometry2 ``tf2_ros/src/static_transform_broadcaster_program.cpp``
(Humble and later; it reads each value with ``std::stod``): ``T_parent_child`` of ``../shared/conventions.md``
published with ``frame_id = parent`` and ``child_frame_id = child``, translation in metres and rotation as the
unit quaternion ``(x, y, z, w)`` with ``w >= 0``, every float at full precision (Python ``repr``). Node names are
``static_tf_`` and the child frame's name (characters a ROS name cannot hold become ``_``; a clash gets a
number), so the publishers do not share a name in the ROS graph. The frames are those of
:func:`~backend.exports.frame_tree.export_frames` in the chosen convention; a NaN or infinity is refused
(:class:`InputError` naming the frame).
"""

from __future__ import annotations

import json
import re

from backend.core.finite import require_finite
from backend.core.rig import Rig
from backend.exports.formats import Convention
from backend.exports.frame_tree import ExportedFrame, export_frames
from backend.exports.rig_transforms import quaternion_xyzw
from backend.exports.yaml_fields import floats

NODE_PREFIX = "static_tf_"
_NOT_IN_ROS_NAME = re.compile(r"[^A-Za-z0-9_]")

_HEADER = '''"""ROS 2 launch file written by Calibration Studio{about}.

One tf2_ros static_transform_publisher per frame (T_parent_child: translation in metres, rotation as a unit
quaternion x, y, z, w), cameras in the {convention} convention. Run it with: ros2 launch <this file>
"""

from launch import LaunchDescription
from launch_ros.actions import Node


def generate_launch_description():
    return LaunchDescription([
'''


def dump_ros2_launch(rig: Rig, convention: Convention = "optical", about: str = "") -> str:
    """Python source of the launch file publishing every frame of ``rig`` in ``convention``; ``about`` (e.g.
    ``"for session demo"``) completes the module docstring's first line."""
    names: set[str] = set()
    nodes = [_node(frame, _node_name(frame.child, names)) for frame in export_frames(rig, convention)]
    header = _HEADER.format(about=f" {about}" if about else "", convention=convention)
    return header + "".join(nodes) + "    ])\n"


def static_transform_arguments(frame: ExportedFrame) -> list[str]:
    """The ``static_transform_publisher`` arguments publishing ``frame`` (flags and values, as strings)."""
    require_finite({"T_parent_child": frame.T_parent_child}, f"launch file: frame {frame.child!r}", frame.sensor)
    x, y, z = floats(frame.T_parent_child[:3, 3])
    qx, qy, qz, qw = floats(quaternion_xyzw(frame.T_parent_child))
    values = {"x": x, "y": y, "z": z, "qx": qx, "qy": qy, "qz": qz, "qw": qw}
    arguments = [word for name, value in values.items() for word in (f"--{name}", repr(value))]
    return [*arguments, "--frame-id", frame.parent, "--child-frame-id", frame.child]


def _node(frame: ExportedFrame, name: str) -> str:
    """One ``Node(...)`` entry of the launch description."""
    words = [json.dumps(word) for word in static_transform_arguments(frame)]
    lines = "".join(f"                {', '.join(words[start:end])},\n" for start, end in ((0, 6), (6, 14), (14, 18)))
    return (
        "        Node(\n"
        '            package="tf2_ros",\n'
        '            executable="static_transform_publisher",\n'
        f"            name={json.dumps(name)},\n"
        "            arguments=[\n"
        f"{lines}"
        "            ],\n"
        "        ),\n"
    )


def _node_name(child: str, taken: set[str]) -> str:
    """A ROS node name for the publisher of ``child`` not yet in ``taken`` (which it joins)."""
    base = NODE_PREFIX + _NOT_IN_ROS_NAME.sub("_", child)
    name, count = base, 1
    while name in taken:
        count += 1
        name = f"{base}_{count}"
    taken.add(name)
    return name
