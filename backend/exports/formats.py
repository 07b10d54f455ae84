"""The export formats and frame conventions by name: what the API, the studio and the CLI offer.

Kept free of heavy imports so the command line can build its options from it without loading the exporters.
"""

from __future__ import annotations

from typing import Literal

ExportFormat = Literal["camera_info", "opencv", "camera-json", "mrcal", "rig", "kalibr", "urdf", "launch",
                       "pose-table"]
EXPORT_FORMATS: dict[str, str] = {
    "camera_info": "ROS camera_info YAML (camera_calibration_parsers)",
    "opencv": "OpenCV FileStorage YAML",
    "camera-json": "the camera JSON of the conventions: any model (photogrammetric and splined included), with its "
                   "sigmas",
    "mrcal": "mrcal's .cameramodel: pinhole-radtan (LENSMODEL_OPENCV5) and the splined model",
    "rig": "the rig's transforms with sigmas and static_transform_publisher lines",
    "kalibr": "Kalibr camchain YAML (T_cn_cnm1 chain; with an IMU, camchain-imucam)",
    "urdf": "URDF: one link per frame, one fixed joint per non-root frame (origin xyz, rpy)",
    "launch": "ROS 2 Python launch file: one tf2_ros static_transform_publisher per frame",
    "pose-table": "CSV of the depth nodes' poses in the world: X, Y, Z (m), RotZ, RotY, RotX (deg), 1-sigma",
}
"""Every format of :data:`ExportFormat`, in the order the CLI and the API list them, with what it holds."""

Convention = Literal["optical", "body"]
CONVENTIONS: dict[str, str] = {
    "optical": "cameras as stored: each camera frame is its optical frame (x right, y down, z forward)",
    "body": "each camera CAM as a body frame (x forward, y left, z up) with a fixed child CAM_optical_frame "
            "(REP 103/105 practice); LiDARs and other frames unchanged",
}
"""The frame conventions of the rig, URDF and launch exports (see :mod:`backend.exports.frame_tree`)."""

CONVENTION_FORMATS = ("rig", "urdf", "launch")
"""The formats written in a chosen :data:`Convention`; the others describe cameras in their optical frames."""
