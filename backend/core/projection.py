"""LiDAR (or any) points drawn onto a camera image, and image colours taken onto the points.

Geometry only: :func:`project_cloud` maps points from a sensor frame into a camera's
pixels (frames and pixels as in ``conventions.md``: ``T_camera_sensor`` maps sensor
points into the camera's optical frame, x right, y down, z forward; the centre of
the top-left pixel is (0, 0), so the image spans ``[-0.5, W - 0.5) x [-0.5, H - 0.5)``),
dropping what the camera cannot see and, optionally, what a nearer surface hides.
:mod:`backend.core.colour_maps` colours the kept points (by depth, intensity or height, on
TURBO), :func:`draw_points` paints them into the image, and
:func:`colourise_cloud` is the reverse view: each point takes its pixel's colour.

Works the same for a 3D LiDAR, a 2D scanner (points with z = 0 in its frame) and a
depth camera's points.

Speed (the studio redraws on every slider move; ``benchmarks/overlay.py`` measures it): the
cloud is projected in chunks of :data:`CHUNK_POINTS` points, so that each step's temporaries
stay in the CPU's cache, and in float32 after the float64 rigid transform (float64 throughout
on request); the largest temporaries live in buffers reused from call to call; the z-buffers
are ``np.minimum.at`` / ``np.maximum.at`` over small integer keys; the image-sized steps are
OpenCV's.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass

import cv2
import numpy as np

from backend.core.camera import CameraIntrinsics
from backend.core.camera_inverse import visible_radius

MIN_DEPTH_M = 1e-3
"""Points nearer than this (z in the camera frame, m) count as behind the camera."""
OCCLUSION_MARGIN = 0.05
"""A point is hidden if it lies more than this fraction of the nearest depth behind the
nearest point of its pixel block (5 %: 10 cm at 2 m, 1 m at 20 m). Relative, because the
depth spread a slanted surface covers within one block grows with its distance."""
CHUNK_POINTS = 65_536
"""Points projected (and drawn) per pass: a pass's float32 temporaries (256 kB each) stay in
the CPU's cache; one pass over a 1M-point cloud is about 1.5x slower."""
ZBUFFER_LANES = 4
"""Copies of the occlusion filter's block z-buffer that consecutive points take turns in (see project_cloud)."""
PARALLEL_MIN_POINTS = 262_144
"""Clouds of at least this many points are projected by two threads, the caller's and a helper, each taking
half of the chunks (numpy's and OpenCV's loops release the GIL); the kept points are then gathered in order."""


class _Scratch:
    """Named work arrays that :func:`project_cloud` and :func:`draw_points` reuse from call to call.

    Fresh memory costs a page fault on first touch (about 3 us per 4 kB page on the 2-core
    VM the benchmark runs on: 12 ms for the image-sized temporaries of one 1280x720
    overlay, as much as the drawing itself), so the largest temporaries are kept: about
    25 MB for a 1280x720 image and 1M points. One set for the process; a thread that finds
    it in use works with its own, fresh one.
    """

    def __init__(self) -> None:
        self._buffers: dict[str, np.ndarray] = {}

    def array(self, name: str, shape: tuple[int, ...], dtype: type) -> np.ndarray:
        """An uninitialised C-contiguous ``shape`` array of ``dtype`` in the buffer ``name`` (grown if too small)."""
        size = math.prod(shape) * np.dtype(dtype).itemsize
        buffer = self._buffers.get(name)
        if buffer is None or buffer.size < size:
            buffer = self._buffers[name] = np.empty(size, np.uint8)
        return buffer[:size].view(dtype).reshape(shape)


_SCRATCH = _Scratch()
_SCRATCH_LOCK = threading.Lock()


@contextmanager
def _scratch() -> Iterator[_Scratch]:
    """The process's :class:`_Scratch` while no other thread uses it, else a fresh one."""
    if not _SCRATCH_LOCK.acquire(blocking=False):
        yield _Scratch()
        return
    try:
        yield _SCRATCH
    finally:
        _SCRATCH_LOCK.release()


@dataclass
class Projection:
    """The points of a cloud a camera sees, row ``i`` of each array being one point."""

    uv: np.ndarray
    """(M, 2) pixel coordinates (u right, v down, px); float32 unless projected with ``dtype=np.float64``."""
    depth_m: np.ndarray
    """(M,) z of each point in the camera's optical frame (m), in the same dtype as :attr:`uv`."""
    index: np.ndarray
    """(M,) int64 row of each point in the input cloud."""

    def __len__(self) -> int:
        return len(self.index)


def project_cloud(
    points_sensor: np.ndarray,
    T_camera_sensor: np.ndarray,
    camera: CameraIntrinsics,
    *,
    range_m: tuple[float, float] | None = None,
    occlusion_px: int = 0,
    occlusion_margin: float = OCCLUSION_MARGIN,
    dtype: type[np.floating] = np.float32,
) -> Projection:
    """Project (N, 3) points in a sensor's frame (m) into ``camera``, keeping those it sees.

    Dropped: NaN / inf points; points behind the camera (z <= :data:`MIN_DEPTH_M`);
    points whose normalised radius (tan of the angle off the optical axis) exceeds what
    the image corners reach (:func:`~backend.core.camera_inverse.visible_radius`), since
    a strong distortion polynomial folds such points back into the image; points that
    land outside the image; with ``range_m = (lo, hi)``, points whose Euclidean range
    from the *sensor's* origin (m) is outside ``[lo, hi]``; with ``occlusion_px > 0``,
    points hidden by a nearer surface: the image is cut into ``occlusion_px``-sized
    square blocks and a block keeps only the points within ``occlusion_margin`` (a
    fraction of depth) of its nearest one.

    The rigid transform is always float64 (so a cloud far from its frame's origin loses
    nothing); the rest runs in ``dtype``. float32 (the default, about 1.4x as fast) is
    within 1e-3 px (typically 2e-4 px) and 1e-6 relative depth of float64; only a point
    that close to an image, block, cone or range edge can come out on the other side of it.
    """
    dtype = np.dtype(dtype)
    if dtype not in (np.float32, np.float64):
        raise ValueError(f"dtype must be float32 or float64, not {dtype}")
    points = np.asarray(points_sensor).reshape(-1, 3)
    T = np.asarray(T_camera_sensor, dtype=np.float64)
    r2_max = visible_radius(camera) ** 2
    r2_window = None if range_m is None else (float(range_m[0]) ** 2, float(range_m[1]) ** 2)
    # Room for every point; the chunks' kept points are appended. Only the rows written are ever
    # touched (memory is mapped on first touch), and the arrays returned are views of the first rows.
    out = Projection(np.empty((len(points), 2), dtype), np.empty(len(points), dtype), np.empty(len(points), np.int64))
    occlusion = None
    if occlusion_px > 0:
        blocks_across = -(-camera.width // occlusion_px)
        off_image = blocks_across * -(-camera.height // occlusion_px)  # one more block, for the points off the image
        occlusion = (occlusion_px, blocks_across, off_image,
                     (np.arange(min(CHUNK_POINTS, len(points))) % ZBUFFER_LANES * (off_image + 1)).astype(np.int32))
    starts = list(range(0, len(points), CHUNK_POINTS))
    job = (points, T, camera, r2_max, r2_window, dtype, occlusion)
    halves = [starts]
    if len(points) >= PARALLEL_MIN_POINTS and len(starts) > 1:
        halves = [starts[:len(starts) // 2], starts[len(starts) // 2:]]
        helper = _POOL.submit(_project_chunks_on_helper, halves[1], *job)
    with _scratch() as scratch:
        passes = [_project_chunks(halves[0], *job, scratch)]
    if len(halves) > 1:
        passes.append(helper.result())
    nearest = None
    if occlusion is not None:
        nearest = passes[0][1] if len(passes) == 1 else np.minimum(passes[0][1], passes[1][1])
        nearest = nearest.min(axis=0)
        nearest *= 1.0 + occlusion_margin  # the farthest depth each block keeps
        nearest[off_image] = -np.inf  # keeps nothing
    if len(passes) == 1:
        count = _gather(out, passes[0][0], nearest)
    else:
        # Each thread gathers its half's kept points; the second half's go after the first's, whose count
        # the caller's thread passes on as soon as it knows it (before it writes them).
        first_count: Future = Future()
        helper = _POOL.submit(_gather, out, passes[1][0], nearest, first_count)
        _gather(out, passes[0][0], nearest, count=first_count)
        count = helper.result()
    return Projection(out.uv[:count], out.depth_m[:count], out.index[:count])


_POOL = ThreadPoolExecutor(max_workers=1, thread_name_prefix="project_cloud")
_HELPER = threading.local()
"""The helper thread's own :class:`_Scratch`, kept from call to call like the process's."""


def _project_chunks_on_helper(starts: list[int], *job) -> tuple[list[tuple], np.ndarray | None]:
    """:func:`_project_chunks` on the helper thread, with its own work arrays."""
    if not hasattr(_HELPER, "scratch"):
        _HELPER.scratch = _Scratch()
    return _project_chunks(starts, *job, _HELPER.scratch)


def _project_chunks(starts: list[int], points: np.ndarray, T: np.ndarray, camera: CameraIntrinsics, r2_max: float,
                    r2_window: tuple[float, float] | None, dtype: np.dtype, occlusion: tuple | None,
                    scratch: _Scratch) -> tuple[list[tuple], np.ndarray | None]:
    """The chunks of ``points`` that begin at rows ``starts``, projected (see :func:`_project_chunk`): per chunk
    ``(start, row, u, v, z, seen)``, ``seen`` being with ``occlusion`` each point's block (the one after the
    last for points off the image or range), and the lanes' z-buffer over blocks (or None without occlusion).

    ``occlusion`` is (block size px, blocks across, the off-image block, each chunk row's lane offset).
    """
    chunks, nearest = [], None
    if occlusion is not None:
        occlusion_px, blocks_across, off_image, lanes = occlusion
        # Consecutive points mostly share a block, and each np.minimum.at update then waits for the one
        # before; spread over ZBUFFER_LANES copies of the z-buffer (point i into copy i % lanes) they do
        # not (2x faster). The copies are merged once all chunks are in.
        nearest = np.full((ZBUFFER_LANES, off_image + 1), np.inf, dtype)
    for start in starts:
        row, u, v, z, seen = _project_chunk(points[start:start + CHUNK_POINTS], T, camera, r2_max, r2_window, dtype,
                                            scratch)
        if occlusion is not None:
            # Blocks of all the chunk's points, those off the image (or range) put into their own
            # block: a cheaper way to leave them out than compacting the arrays once more.
            seen = np.where(seen, _blocks(u, v, occlusion_px, blocks_across), off_image)
            # A z-buffer over blocks (unbuffered, so repeated blocks all count), one lane per point.
            np.minimum.at(nearest.reshape(-1), seen + lanes[:len(seen)], z)
        chunks.append((start, row, u, v, z, seen))
    return chunks, nearest


def _gather(out: Projection, chunks: list[tuple], nearest: np.ndarray | None, offset: Future | None = None,
            count: Future | None = None) -> int:
    """Append the kept points of ``chunks`` (as :func:`_project_chunks` gives them; kept: seen, and with the
    blocks' farthest kept depths ``nearest``, not hidden) to ``out`` after the row ``offset`` gives (else
    0); sets ``count`` to the rows ``out`` holds after them as soon as that is known, and returns it.
    """
    keeps = [np.flatnonzero(seen if nearest is None else z <= np.take(nearest, seen)) for _, _, _, _, z, seen in chunks]
    start_row = 0 if offset is None else offset.result()
    end_row = start_row + sum(len(keep) for keep in keeps)
    if count is not None:
        count.set_result(end_row)
    row_count = start_row
    for (start, row, u, v, z, _), keep in zip(chunks, keeps, strict=True):
        row_count = _append(out, row_count, start, keep, row, u, v, z)
    return end_row


def _append(out: Projection, count: int, start: int, keep: np.ndarray, row: np.ndarray, u: np.ndarray, v: np.ndarray,
            z: np.ndarray) -> int:
    """Write entries ``keep`` of a chunk's points (``row`` in the chunk that starts at row ``start`` of the cloud,
    ``u``, ``v``, ``z``) after the first ``count`` points of ``out``; returns how many ``out`` holds then."""
    rows = slice(count, count + len(keep))
    targets = out.uv[rows, 0], out.uv[rows, 1], out.depth_m[rows], out.index[rows]
    for source, target in zip((u, v, z, row), targets, strict=True):
        np.take(source, keep, out=target, mode="clip")  # "clip" (the entries are valid) writes unbuffered
    out.index[rows] += start
    return rows.stop


def _project_chunk(points: np.ndarray, T: np.ndarray, camera: CameraIntrinsics, r2_max: float,
                   r2_window: tuple[float, float] | None, dtype: np.dtype,
                   scratch: _Scratch) -> tuple[np.ndarray, ...]:
    """The (n, 3) sensor-frame ``points`` within the cone the camera sees: their ``row`` in ``points`` (int64),
    ``u``, ``v`` (px), ``z`` (m) and whether each lands on the image (and in the range window).

    All but the occlusion filter of :func:`project_cloud`; ``r2_max`` is the squared visible
    radius, ``r2_window`` the squared range window (m^2) or None; ``dtype`` that of u, v and z.
    """
    with np.errstate(invalid="ignore", over="ignore"):  # NaN / inf points are expected, and dropped below
        # In float64 (cv2.transform: 2x numpy's matmul), then (3, n) in `dtype`: each coordinate is a
        # contiguous row, so every step below runs on 1-D arrays. Both in reused buffers (the largest
        # temporaries of a chunk).
        transformed = scratch.array("transformed", (1, len(points), 3), np.float64)
        transformed = cv2.transform(np.ascontiguousarray(points, dtype=np.float64).reshape(1, -1, 3), T[:3],
                                    dst=transformed)
        cam = scratch.array("camera", (3, len(points)), dtype)
        np.copyto(cam, transformed.reshape(-1, 3).T)
        x, y, z = cam
        # In front, within the cone the image corners reach ((x/z)^2 + (y/z)^2 <= r^2, as z > 0; beyond it the
        # distortion may fold points back in), and finite: NaN fails every comparison, an infinite x or y fails
        # the cone and an infinite z fails z < inf, so no separate isfinite pass is needed.
        in_cone = x * x
        in_cone += y * y
        bound = z * z
        bound *= r2_max
        in_cone = in_cone <= bound
        in_cone &= z > MIN_DEPTH_M
        in_cone &= z < np.inf
    row = np.flatnonzero(in_cone)
    x, y, z = np.take(cam, row, axis=1)  # one gather for the three rows; 3x faster than cam[:, row]
    seen = None
    if r2_window is not None:
        # The range from the sensor's origin, which sits at T's translation in the camera frame.
        tx, ty, tz = T[:3, 3].tolist()  # Python floats keep float32 arrays float32
        r2 = (x - tx) ** 2 + (y - ty) ** 2 + (z - tz) ** 2
        seen = (r2 >= r2_window[0]) & (r2 <= r2_window[1])
    x /= z  # x and y are this chunk's own copies, so dividing in place is safe
    y /= z
    u, v = camera.normalised_to_pixels(x, y)
    in_image = _in_image(u, v, camera.width, camera.height)
    return row, u, v, z, in_image if seen is None else seen & in_image


def _in_image(u: np.ndarray, v: np.ndarray, width: int, height: int) -> np.ndarray:
    """Whether pixel coordinates (px) fall on the image, ``[-0.5, width - 0.5) x [-0.5, height - 0.5)``; NaN do not."""
    inside = u >= -0.5
    inside &= u < width - 0.5
    inside &= v >= -0.5
    inside &= v < height - 0.5
    return inside


def _keep(mask: np.ndarray, *arrays: np.ndarray) -> tuple[np.ndarray, ...]:
    """Each of ``arrays`` (same length as ``mask``) restricted to where ``mask`` holds."""
    rows = np.flatnonzero(mask)
    return tuple(np.take(a, rows, axis=0) for a in arrays)  # 7x faster than a[mask], 1.3x than a[rows]


def _blocks(u: np.ndarray, v: np.ndarray, block_px: int, blocks_across: int) -> np.ndarray:
    """int32 row-major number of the ``block_px``-sized image block of each pixel coordinate (``u``, ``v``, px)."""
    # u, v >= -0.5 on the image, so truncation is the floor; int32 with a scalar divisor keeps it SIMD-fast.
    # Off the image the numbers are meaningless (the caller replaces them), hence no warnings.
    with np.errstate(invalid="ignore"):
        block = (v + 0.5).astype(np.int32)
        cols = (u + 0.5).astype(np.int32)
    block //= block_px
    block *= blocks_across
    cols //= block_px
    block += cols
    return block


def draw_points(image: np.ndarray, uv: np.ndarray, colours: np.ndarray, radius_px: int = 1) -> np.ndarray:
    """A BGR uint8 copy of ``image`` (BGR or gray) with points at ``uv`` (M, 2, px) painted in ``colours``.

    ``colours`` is (M, 3) uint8 RGB, as the colour functions here give. Each point is a
    square of side ``2 * radius_px + 1`` centred on its nearest pixel; where squares
    overlap, the later point is on top (as if painted in order). Instead of writing
    ``(2r + 1)**2`` shifted copies of every point, each point's row number is written once
    into a layer (the largest where points share a pixel; -1 where there is none) and the
    layer is grey-dilated with a square kernel: the dilation's maximum picks the last point
    covering a pixel, and the cost is one pass over the image whatever the number of points.
    A table lookup then turns each pixel's row number into its point's colour.
    """
    canvas = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR) if image.ndim == 2 else image.copy()
    height, width = canvas.shape[:2]
    uv = np.asarray(uv).reshape(-1, 2)
    if uv.dtype != np.float32:  # float32 pixels (project_cloud's) are rounded as they are
        uv = uv.astype(np.float64, copy=False)
    colours = np.ascontiguousarray(colours, dtype=np.uint8).reshape(-1, 3)
    count = len(uv)
    if len(colours) != count:
        raise ValueError(f"{count} points but {len(colours)} colours")
    if count == 0:
        return canvas
    # Row numbers are exact in float32 below 2**24 points; cv2.dilate takes float32 but not int32.
    layer_dtype = np.float32 if count < 2**24 else np.float64
    # The usual case, all points on the image (project_cloud's), in three quick reductions (NaN fails them too).
    all_inside = bool(uv.min() >= -0.5 and uv[:, 0].max() < width - 0.5 and uv[:, 1].max() < height - 0.5)
    with _scratch() as scratch:
        layer = scratch.array("layer", (height, width), layer_dtype)
        layer.fill(-1)
        for start in range(0, count, CHUNK_POINTS):  # in chunks, so that the temporaries stay small and in cache
            chunk = uv[start:start + CHUNK_POINTS]
            rows = np.arange(start, start + len(chunk), dtype=layer_dtype)
            if not all_inside:
                chunk, rows = _keep(_in_image(chunk[:, 0], chunk[:, 1], width, height), chunk, rows)
            pixel = np.rint(chunk).astype(np.int32)
            flat = pixel[:, 1] * width
            flat += pixel[:, 0]
            np.maximum.at(layer.reshape(-1), flat, rows)  # each pixel's last point: a z-buffer on row numbers
        if radius_px > 0:
            side = 2 * int(radius_px) + 1
            layer = cv2.dilate(layer, np.ones((side, side), np.uint8), dst=layer)
        row = scratch.array("row", (height, width), np.intp)  # np.take's own index type: no hidden conversion
        np.copyto(row, layer, casting="unsafe")  # exact: whole numbers
        # Entry `row` of the table is that point's colour as 4 BGRx bytes read as one uint32, so one np.take
        # paints the whole image. Row -1 (no point) clips to entry 0, but the mask leaves those pixels out.
        table = scratch.array("table", (1, count, 4), np.uint8)
        table = cv2.cvtColor(colours[None], cv2.COLOR_RGB2BGRA, dst=table)
        painted = scratch.array("painted", (height, width), np.uint32)
        np.take(table.reshape(-1).view(np.uint32), row, out=painted, mode="clip")  # "clip" is also unbuffered
        painted_bgr = scratch.array("painted_bgr", (height, width, 3), np.uint8)
        painted_bgr = cv2.cvtColor(painted.view(np.uint8).reshape(height, width, 4), cv2.COLOR_BGRA2BGR,
                                   dst=painted_bgr)
        mask = scratch.array("mask", (height, width), np.uint8)
        np.greater_equal(layer, 0, out=mask.view(bool))
        canvas = cv2.copyTo(painted_bgr, mask, canvas)
    return canvas


def colourise_cloud(
    points_sensor: np.ndarray,
    T_camera_sensor: np.ndarray,
    camera: CameraIntrinsics,
    image: np.ndarray,
    *,
    occlusion_px: int = 4,
    range_m: tuple[float, float] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Colour each of (N, 3) sensor-frame points (m) by the pixel of ``image`` (BGR or gray) it projects to.

    Returns ``(colours, seen)``: (N, 3) uint8 RGB (nearest pixel; zeros where unseen) and
    an (N,) bool that is False for points the camera does not see (see
    :func:`project_cloud`; ``occlusion_px`` keeps hidden points from taking the colour
    of the surface in front of them).
    """
    projection = project_cloud(points_sensor, T_camera_sensor, camera, range_m=range_m, occlusion_px=occlusion_px)
    rgb = cv2.cvtColor(image, cv2.COLOR_GRAY2RGB if image.ndim == 2 else cv2.COLOR_BGR2RGB)
    cols, rows = _pixels(projection.uv)
    rows *= rgb.shape[1]
    rows += cols
    n = len(np.asarray(points_sensor).reshape(-1, 3))
    colours = np.zeros((n, 3), np.uint8)
    # Each pixel's and each point's 3 bytes as one item: 1-D gathers and scatters are numpy's fast ones.
    pixel_items, colour_items = (a.reshape(-1, 3).view(np.dtype((np.void, 3))).reshape(-1) for a in (rgb, colours))
    colour_items[projection.index] = np.take(pixel_items, rows)
    seen = np.zeros(n, bool)
    seen[projection.index] = True
    return colours, seen


def _pixels(uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Column and row (int64) of the pixel nearest each of (M, 2) pixel coordinates (px), rounded in their dtype."""
    pixel = np.rint(np.asarray(uv).reshape(-1, 2)).astype(np.int64)
    return pixel[:, 0], pixel[:, 1]
