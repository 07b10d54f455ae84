"""Simulated marker targets: camera images and LiDAR clouds of V-targets and of a wall test field.

Camera images: every target is a set of flat printed plates (:class:`MarkerPlate`), rendered exactly as the
calibration boards are (:func:`backend.sim.board_renderer.render_plates`: each sub-pixel's ray through the
distorted lens meets the plate, a mip-mapped texture of the print is looked up, lighting, blur and noise follow).
A plate's frame is a board's: origin at the print's top-left corner, x right, y down, z into the plate (m), so
the camera sees the print from plate z < 0. A V-target (:class:`~backend.core.v_target.VTarget`) is its two faces'
plates; a wall test field (:class:`~backend.core.test_field.TestField`) is a small plate per marker, standing off
a light-grey wall plate at the surveyed centre.

The simulated test field is a grid of markers on a wall whose frame is a board's too: x right, y down, z into
the wall (m), origin at the grid's centre. Each marker stands off the wall by a random relief, so the field is not
quite planar; :func:`field_views` photographs it with the disaster-response robot's FLIR Blackfly
(:func:`disaster_response_camera`).

LiDAR clouds (:func:`v_target_cloud`): the two plates (:data:`PLATE_THICKNESS_M` thick behind their prints), a
ground plane and a wall behind the target are ray cast with Open3D's ``RaycastingScene``, in the LiDAR frame
(x forward, y left, z up, m), for a Livox Avia's non-repetitive rosette or a VLP-16's sixteen rings. Ranges get
Gaussian noise along the ray; intensities follow :mod:`backend.sim.lidar_scene` (white plate, darker ink where
a marker is printed, incidence-dependent).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from backend.core.camera import CameraIntrinsics
from backend.core.markers import marker_image
from backend.core.test_field import TestField, read_survey, survey_text
from backend.core.transforms import from_xyz_ypr, invert, look_at, make_T, transform_points
from backend.core.v_target import VTarget
from backend.sim.board_renderer import plate_texture, render_plates
from backend.sim.lidar_scene import BOARD_INK_INTENSITY, LABELS, _box, _concat, _plate, label_reflectivity

TEXELS_PER_M = 1000.0
"""Resolution of the simulated marker prints (texels per metre: a millimetre each)."""
WALL_TEXELS_PER_M = 200.0
"""Resolution of the (plain) wall's print: fine enough for a sharp edge at a few metres."""
WALL_GREY = 200
"""The wall's grey level as a print (0 ink .. 255 paper): a light-grey wall behind the white-bordered markers."""
WALL_MARGIN_M = 0.6
"""How far the wall extends beyond the outermost marker centres (m)."""
WALL_GAP_M = 0.01
"""How far the wall lies behind the deepest marker (m)."""

FIELD_GRID = (8, 5)
"""Columns and rows of markers of the default simulated test field."""
FIELD_SPACING_M = (0.45, 0.45)
"""Distance between neighbouring marker centres of the default field, along x and y (m)."""
VIEW_TILT_DEG = (15.0, 35.0)
"""Range of the angle between a test-field view's optical axis and the wall's normal (deg)."""
NEAR_VIEW_M = (2.5, 2.8)
"""Range of the distance from a near test-field view to the point it aims at (m)."""
FAR_VIEW_M = (3.0, 3.4)
"""Range of the distance from a far test-field view to the point it aims at (m)."""
AIM_OFFSET_M = (0.6, 0.35)
"""Largest offset, along the wall's x and y, of the point a test-field view aims at from the field's centre (m)."""

BLACKFLY_SIZE_PX = (1280, 1024)
"""The simulated FLIR Blackfly's image width and height (px)."""
BLACKFLY_PRINCIPAL_DISTANCE_PX = 4e-3 / 4.8e-6
"""The Blackfly's 4 mm lens on 4.8 um pixels (px)."""
BLACKFLY_PRINCIPAL_POINT_PX = (646.3, 508.9)
"""The Blackfly's principal point (px)."""

PLATE_THICKNESS_M = 0.01
"""Thickness of each V-target plate behind its print (m), as the LiDAR sees it."""
GROUND_BELOW_TARGET_M = 1.0
"""Default height of the target's lowest corner above the ground (m)."""
GROUND_SIZE_M = 200.0
"""Side of the square ground slab, centred under the LiDAR (m)."""
BACK_WALL_BEHIND_M = 2.0
"""Distance from the target's centre to the wall behind it, away from the LiDAR (m)."""
BACK_WALL_SIZE_M = (40.0, 8.0)
"""Width and height of the wall behind the target (m), standing on the ground."""
INTENSITY_TEXELS_PER_M = 250.0
"""Resolution of the prints in which a LiDAR return looks up ink or paper (texels per metre)."""

AVIA_FOV_DEG = (70.4, 77.2)
"""Livox Avia's field of view, horizontal and vertical (deg)."""
AVIA_POINTS_PER_S = 240_000
"""Livox Avia's returns per second (single return)."""
AVIA_PRISM_HZ = (277.7, 174.6)
"""Rates of the Avia model's two counter-rotating prisms (Hz): their ratio is not rational, so the rosette never
repeats and covers more of the field of view the longer it integrates."""
VLP16_ELEVATIONS_DEG = np.linspace(-15.0, 15.0, 16)
"""Elevation of each of the VLP-16's rings (deg)."""
VLP16_AZIMUTH_STEP_DEG = 0.2
"""Azimuth between the VLP-16's firings (deg)."""
VLP16_ROTATION_HZ = 10.0
"""The VLP-16's revolutions per second."""
LidarPattern = Literal["livox-avia", "vlp16"]


@dataclass(frozen=True)
class MarkerPlate:
    """A flat plate carrying a print, posed in a camera's optical frame."""

    T_camera_plate: np.ndarray
    """4x4 pose of the plate (m); its frame is a board's: origin at the print's top-left corner, x right, y down,
    z into the plate."""
    print_image: np.ndarray
    """(H, W) uint8 grayscale print, white 255."""
    size_m: tuple[float, float]
    """Width and height of the print (m)."""


def render_marker_plates(
    camera: CameraIntrinsics,
    plates: Sequence[MarkerPlate],
    rng: np.random.Generator,
    *,
    blur_px: float = 0.7,
    noise_sigma: float = 2.0,
    brightness: float | None = None,
    background: bool = True,
) -> np.ndarray:
    """A uint8 grayscale (H, W) image of ``plates`` as ``camera`` sees them (its distortion rendered exactly).

    Nearer plates hide farther ones (painter's order, :func:`~backend.sim.board_renderer.render_plates`); a plate
    seen from behind or not wholly in front of the camera is not drawn. ``rng`` is the only source of randomness
    (lighting, background, noise); ``blur_px`` is the lens blur's sigma (px), ``noise_sigma`` the sensor noise's
    (grey levels), ``brightness`` the grey level of white paper at the image centre (drawn when None), and
    ``background`` False leaves black behind the plates.
    """
    textures = [(plate_texture(plate.print_image, _print_corners(plate.size_m)), plate.T_camera_plate)
                for plate in plates]
    return render_plates(camera, textures, rng, blur_px=blur_px, noise_sigma=noise_sigma, brightness=brightness,
                         background=background)


def _print_corners(size_m: tuple[float, float]) -> np.ndarray:
    """(4, 3) plate-frame corners (m) of a print of ``size_m``: TL, TR, BR, BL."""
    width_m, height_m = size_m
    return np.array([[0.0, 0.0, 0.0], [width_m, 0.0, 0.0], [width_m, height_m, 0.0], [0.0, height_m, 0.0]])


def _cell_texels(dictionary: str, marker_m: float, texels_per_m: float) -> tuple[int, int]:
    """Cells along a marker's side (its black border included) and the whole texels per cell nearest
    ``texels_per_m`` for a ``marker_m`` marker."""
    cells = marker_image(dictionary, 0, 1).shape[0]
    return cells, max(1, round(marker_m * texels_per_m / cells))


# --- V-targets -----------------------------------------------------------------------------------------------------

def v_target_prints(target: VTarget, texels_per_m: float = TEXELS_PER_M) -> list[np.ndarray]:
    """Each face's print, face 0 then face 1: uint8 (H, W), white with the face's markers upright at
    ``target.marker_centres_print``, about ``texels_per_m`` texels per metre (whole texels over the plate).

    Markers land at their exact sub-texel positions (anti-aliased), so the printed corners are where
    ``target.marker_corners`` puts them, to well under a texel.
    """
    size_texels = np.rint(np.array([target.width_m, target.height_m]) * texels_per_m).astype(int)
    scale = size_texels / np.array([target.width_m, target.height_m])  # texels per metre along x and y
    _, cell_texels = _cell_texels(target.dictionary, target.marker_m, texels_per_m)
    prints = []
    for face_ids in target.marker_ids.reshape(2, -1):
        face_print = np.full(size_texels[::-1], 255, np.uint8)
        for marker_id, centre_m in zip(face_ids, target.marker_centres_print, strict=True):
            marker = marker_image(target.dictionary, marker_id, cell_texels)
            # Marker pixel j is centred at print x = x0 + (j + 0.5) * side / n (m), texel i at (i + 0.5) / scale.
            texels_per_pixel = target.marker_m * scale / marker.shape[0]
            offset = (centre_m - target.marker_m / 2) * scale + 0.5 * texels_per_pixel - 0.5
            M = np.array([[texels_per_pixel[0], 0.0, offset[0]], [0.0, texels_per_pixel[1], offset[1]]])
            placed = cv2.warpAffine(marker, M, tuple(size_texels), flags=cv2.INTER_LINEAR, borderValue=255)
            np.minimum(face_print, placed, out=face_print)
        prints.append(face_print)
    return prints


def v_target_plates(target: VTarget, T_camera_target: np.ndarray) -> list[MarkerPlate]:
    """The target's two faces as plates (face 0, face 1) for a target at ``T_camera_target`` (4x4, m)."""
    T_camera_face = np.asarray(T_camera_target, dtype=float) @ target.T_target_face
    return [MarkerPlate(T, face_print, (target.width_m, target.height_m))
            for T, face_print in zip(T_camera_face, v_target_prints(target), strict=True)]


def render_v_target_image(camera: CameraIntrinsics, target: VTarget, T_camera_target: np.ndarray,
                          rng: np.random.Generator, **render: Any) -> np.ndarray:
    """A uint8 (H, W) image of ``target`` at ``T_camera_target`` (4x4, m); ``render`` as
    :func:`render_marker_plates` takes it."""
    return render_marker_plates(camera, v_target_plates(target, T_camera_target), rng, **render)


# --- the wall test field -------------------------------------------------------------------------------------------

def simulated_test_field(
    folder: Path,
    *,
    dictionary: str = "DICT_4X4_50",
    marker_m: float = 0.15,
    cols: int = FIELD_GRID[0],
    rows: int = FIELD_GRID[1],
    spacing_m: tuple[float, float] = FIELD_SPACING_M,
    relief_m: float = 0.02,
    seed: int = 0,
) -> tuple[str, np.ndarray]:
    """Survey a simulated wall test field into ``folder/survey.csv``; returns its spec
    (``testfield:DICT:MARKER:folder/survey.csv``) and the (N, 3) true marker centres (m, the wall's frame).

    The markers, ids ``0 .. cols*rows - 1`` read left to right and top to bottom, sit on a ``cols x rows`` grid
    ``spacing_m`` apart (along x, y), centred on the wall frame's origin; each stands off the wall by a random
    amount within ``relief_m`` along z. The centres are those of the file (0.1 mm), so the survey is exact.
    """
    col, row = np.meshgrid(np.arange(cols) - (cols - 1) / 2, np.arange(rows) - (rows - 1) / 2)
    relief = np.random.default_rng(seed).uniform(-relief_m, relief_m, cols * rows)
    centres_m = np.column_stack([col.ravel() * spacing_m[0], row.ravel() * spacing_m[1], relief])
    survey = Path(folder) / "survey.csv"
    survey.write_text(survey_text(np.arange(cols * rows), centres_m))
    return f"testfield:{dictionary}:{marker_m:g}:{survey}", read_survey(survey)[1]


def field_plates(field: TestField, T_camera_wall: np.ndarray) -> list[MarkerPlate]:
    """The wall and its markers as plates, for a field surveyed in a frame like :func:`simulated_test_field`'s (z
    into the wall) and seen at ``T_camera_wall`` (4x4, m).

    Each marker is a plate of its own facing -z at its surveyed centre, with a white quiet zone one cell wide;
    the wall is a light-grey plate :data:`WALL_GAP_M` behind the deepest marker, :data:`WALL_MARGIN_M` beyond
    the outermost centres.
    """
    T_camera_wall = np.asarray(T_camera_wall, dtype=float)
    low, high = field.centres_m.min(axis=0), field.centres_m.max(axis=0)
    wall_size_m = high[:2] - low[:2] + 2 * WALL_MARGIN_M
    wall_print = np.full(np.rint(wall_size_m[::-1] * WALL_TEXELS_PER_M).astype(int), WALL_GREY, np.uint8)
    T_wall_print = make_T(np.eye(3), [*(low[:2] - WALL_MARGIN_M), high[2] + WALL_GAP_M])
    plates = [MarkerPlate(T_camera_wall @ T_wall_print, wall_print, (wall_size_m[0], wall_size_m[1]))]
    cells, cell_texels = _cell_texels(field.dictionary, field.marker_m, TEXELS_PER_M)
    side_m = field.marker_m * (cells + 2) / cells
    for marker_id, centre_m in zip(field.ids, field.centres_m, strict=True):
        marker_print = np.pad(marker_image(field.dictionary, marker_id, cell_texels), cell_texels,
                              constant_values=255)
        T_wall_marker = make_T(np.eye(3), centre_m - [side_m / 2, side_m / 2, 0.0])
        plates.append(MarkerPlate(T_camera_wall @ T_wall_marker, marker_print, (side_m, side_m)))
    return plates


def render_test_field_image(camera: CameraIntrinsics, field: TestField, T_camera_wall: np.ndarray,
                            rng: np.random.Generator, **render: Any) -> np.ndarray:
    """A uint8 (H, W) image of the test field at ``T_camera_wall`` (4x4, m); ``render`` as
    :func:`render_marker_plates` takes it."""
    return render_marker_plates(camera, field_plates(field, T_camera_wall), rng, **render)


def disaster_response_camera() -> CameraIntrinsics:
    """The disaster-response robot's FLIR Blackfly as simulated: 1280x1024 px, a 4 mm lens on 4.8 um pixels,
    photogrammetric model with a moderate barrel, decentring and a little affinity and shear."""
    c = BLACKFLY_PRINCIPAL_DISTANCE_PX
    x0, y0 = BLACKFLY_PRINCIPAL_POINT_PX
    return CameraIntrinsics("photogrammetric", *BLACKFLY_SIZE_PX, [[c, 0, x0], [0, c, y0], [0, 0, 1]],
                            [-0.22 / c**2, 0.09 / c**4, -0.012 / c**6, 2e-4 / c, -3e-4 / c, 4e-4, -2.5e-4])


def field_views(n_positions: int = 6, seed: int = 0) -> list[np.ndarray]:
    """``T_camera_wall`` (4x4, m) of :func:`disaster_response_camera` photographing the default field of
    :func:`simulated_test_field` from ``n_positions`` places, each twice: straight, then rolled 90 deg about the
    optical axis.

    The places take turns to the left of the field, above or below its centre and to its right, the first three
    near (:data:`NEAR_VIEW_M`) and the next three far (:data:`FAR_VIEW_M`). Each aims at a point up to
    :data:`AIM_OFFSET_M` from the field's centre with its optical axis tilted :data:`VIEW_TILT_DEG` from the
    wall's normal, so the field is foreshortened differently in every view and, as a photogrammetrist fills the
    frame, the markers come near the image's corners (some views cut off a few; 40 markers in 12 views still
    leave the outermost 15-20 % of the image's diagonal unmeasured, which the lens's projection sigma there shows).
    """
    rng = np.random.default_rng([seed, 5150])
    T_rolled_camera = make_T(Rotation.from_euler("z", 90, degrees=True).as_matrix(), np.zeros(3))
    views = []
    for place in range(n_positions):
        side = place % 3
        azimuth_deg = (180.0, rng.choice([-90.0, 90.0]), 0.0)[side] + rng.uniform(-25.0, 25.0)
        tilt, azimuth = np.radians([rng.uniform(*VIEW_TILT_DEG), azimuth_deg])
        distance_m = rng.uniform(*(FAR_VIEW_M if place // 3 % 2 else NEAR_VIEW_M))
        aim = np.r_[rng.uniform(-1, 1, 2) * AIM_OFFSET_M, 0.0]
        towards_camera = np.array([np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth), -np.cos(tilt)])
        T_camera_wall = invert(look_at(aim + distance_m * towards_camera, aim, np.array([0.0, -1.0, 0.0])))
        views += [T_camera_wall, T_rolled_camera @ T_camera_wall]
    return views


# --- LiDAR ---------------------------------------------------------------------------------------------------------

def v_target_cloud(
    target: VTarget,
    T_lidar_target: np.ndarray,
    rng: np.random.Generator,
    *,
    pattern: LidarPattern = "livox-avia",
    range_sigma_m: float = 0.02,
    seconds: float = 0.5,
    ground_z_m: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """A LiDAR's view of ``target`` at ``T_lidar_target`` (4x4, m): (N, 3) points in the LiDAR frame (x forward,
    y left, z up, m) and their (N,) intensities (0..255).

    The scene is the two plates, a ground plane at ``ground_z_m`` (LiDAR z, m; by default
    :data:`GROUND_BELOW_TARGET_M` below the target's lowest corner) and a wall :data:`BACK_WALL_BEHIND_M` behind
    the target. ``pattern`` is the scan: a Livox Avia's non-repetitive rosette over ``seconds`` (s), or a VLP-16's
    revolutions at 10 Hz. Ranges get Gaussian noise of ``range_sigma_m`` (m) along each ray.
    """
    import open3d as o3d

    T_lidar_target = np.asarray(T_lidar_target, dtype=float)
    T_lidar_face = T_lidar_target @ target.T_target_face
    corners = transform_points(T_lidar_target, target.plate_corners().reshape(-1, 3))
    if ground_z_m is None:
        ground_z_m = corners[:, 2].min() - GROUND_BELOW_TARGET_M
    directions = _scan_directions(pattern, seconds, rng)
    vertices, triangles, labels = _v_target_scene(target, T_lidar_face, corners.mean(axis=0), ground_z_m)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(vertices.astype(np.float32)), o3d.core.Tensor(triangles.astype(np.uint32)))
    rays = np.hstack([np.zeros_like(directions), directions]).astype(np.float32)
    result = scene.cast_rays(o3d.core.Tensor(rays))
    range_m = result["t_hit"].numpy().astype(float)
    hit = np.isfinite(range_m)
    directions, range_m = directions[hit], range_m[hit]
    labels = labels[result["primitive_ids"].numpy()[hit]]
    normals = result["primitive_normals"].numpy()[hit].astype(float)
    points = directions * (range_m + rng.normal(0.0, range_sigma_m, len(range_m)))[:, None]
    reflectivity = label_reflectivity(labels)
    on_plate = np.flatnonzero(labels == LABELS["board"])
    ink = _on_ink(target, T_lidar_face, directions[on_plate] * range_m[on_plate, None])
    reflectivity[on_plate[ink]] = BOARD_INK_INTENSITY
    cos_incidence = np.abs(np.einsum("ij,ij->i", normals, directions))
    intensity = reflectivity * (0.35 + 0.65 * cos_incidence) + rng.normal(0.0, 1.5, len(points))
    return points, np.clip(intensity, 0, 255).astype(np.float32)


def _scan_directions(pattern: LidarPattern, seconds: float, rng: np.random.Generator) -> np.ndarray:
    """(N, 3) unit beam directions (LiDAR frame) of ``seconds`` of ``pattern``, starting at a random moment."""
    if pattern == "livox-avia":
        # Two prisms turning in opposite directions each deflect the beam by half the field of view: a rosette.
        t = rng.uniform(0.0, 3600.0) + np.arange(round(AVIA_POINTS_PER_S * seconds)) / AVIA_POINTS_PER_S
        deflection = 0.5 * (np.exp(2j * np.pi * AVIA_PRISM_HZ[0] * t) + np.exp(-2j * np.pi * AVIA_PRISM_HZ[1] * t))
        azimuth = np.radians(AVIA_FOV_DEG[0] / 2) * deflection.real
        elevation = np.radians(AVIA_FOV_DEG[1] / 2) * deflection.imag
    elif pattern == "vlp16":
        revolutions = max(1, round(seconds * VLP16_ROTATION_HZ))
        columns = round(360.0 / VLP16_AZIMUTH_STEP_DEG)
        start_deg = rng.uniform(0.0, VLP16_AZIMUTH_STEP_DEG, (revolutions, 1))
        azimuth_deg = (start_deg + VLP16_AZIMUTH_STEP_DEG * np.arange(columns)).ravel()
        azimuth = np.radians(np.repeat(azimuth_deg, len(VLP16_ELEVATIONS_DEG)))
        elevation = np.radians(np.tile(VLP16_ELEVATIONS_DEG, len(azimuth_deg)))
    else:
        raise ValueError(f"unknown LiDAR pattern {pattern!r}; expected 'livox-avia' or 'vlp16'")
    return np.column_stack([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth),
                            np.sin(elevation)])


def _v_target_scene(target: VTarget, T_lidar_face: np.ndarray, centre: np.ndarray, ground_z_m: float
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The mesh (vertices, triangles, :data:`LABELS` per triangle; LiDAR frame, m) of the plates, the ground and
    the wall behind the target's ``centre``."""
    print_corners = _print_corners((target.width_m, target.height_m))
    parts: list[tuple[np.ndarray, np.ndarray, str | np.ndarray]] = [
        (*_plate(T, print_corners, PLATE_THICKNESS_M), "board") for T in T_lidar_face]
    parts.append((*_box(make_T(np.eye(3), [0.0, 0.0, ground_z_m - 0.1]), (GROUND_SIZE_M, GROUND_SIZE_M, 0.1)),
                  "floor"))
    heading = np.arctan2(centre[1], centre[0])
    wall_distance_m = np.hypot(centre[0], centre[1]) + BACK_WALL_BEHIND_M + 0.1
    T_lidar_wall = from_xyz_ypr(np.array([wall_distance_m * np.cos(heading), wall_distance_m * np.sin(heading),
                                          ground_z_m]), np.array([heading, 0.0, 0.0]))
    parts.append((*_box(T_lidar_wall, (0.2, *BACK_WALL_SIZE_M)), "wall"))
    return _concat(parts)


def _on_ink(target: VTarget, T_lidar_face: np.ndarray, points_lidar: np.ndarray) -> np.ndarray:
    """Whether each LiDAR-frame point (N, 3) on a plate (m) lies on a marker's black cell of a face's print."""
    ink = np.zeros(len(points_lidar), bool)
    for T, face_print in zip(T_lidar_face, v_target_prints(target, INTENSITY_TEXELS_PER_M), strict=True):
        x, y, z = transform_points(invert(T), points_lidar).T
        col = np.floor(x / target.width_m * face_print.shape[1]).astype(int)
        row = np.floor(y / target.height_m * face_print.shape[0]).astype(int)
        on_print = (np.abs(z) < 1e-3) & (col >= 0) & (col < face_print.shape[1]) & (row >= 0)
        on_print &= row < face_print.shape[0]
        ink[on_print] = face_print[row[on_print], col[on_print]] < 128
    return ink
