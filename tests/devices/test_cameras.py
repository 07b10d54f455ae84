"""UVC camera, image-folder and image I/O tests, all without camera hardware.

OpenCV's ``VideoCapture`` opens video files through the same code path as
cameras, so the UVC driver is exercised with small MJPG AVI files whose frames
encode their index in the pixel values.
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from backend.core.errors import InputError
from backend.devices.base import CaptureDevice, DeviceDisconnected, DeviceError, Sample, create_device
from backend.devices.file_sequence import natural_key
from backend.devices.image_folder import ImageFolder
from backend.devices.image_io import decode_image_bytes, encode_jpeg, encode_png, read_image
from backend.devices.uvc_camera import UvcCamera

CHESSBOARD_JPEG = Path("/work/shared/data/opencv_stereo_chessboard/left01.jpg")
FRAME_SIZE = (320, 240)


def frame_value(index: int) -> int:
    """The background gray level of frame ``index`` in the test videos."""
    return 10 + 20 * index


def write_video(path: Path, frames: int = 10) -> Path:
    """Write an MJPG AVI whose frame ``i`` has background :func:`frame_value` and its number drawn in."""
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*"MJPG"), 10.0, FRAME_SIZE)
    assert writer.isOpened()
    for i in range(frames):
        frame = np.full((FRAME_SIZE[1], FRAME_SIZE[0], 3), frame_value(i), np.uint8)
        cv2.putText(frame, str(i), (10, 40), cv2.FONT_HERSHEY_SIMPLEX, 1.0, (255, 255, 255), 2)
        writer.write(frame)
    writer.release()
    return path


def read_until_disconnected(camera: CaptureDevice) -> tuple[list[Sample], DeviceDisconnected]:
    """Read samples until the device disconnects; return them and the exception."""
    samples = []
    with pytest.raises(DeviceDisconnected) as info:
        for _ in range(1000):
            samples.append(camera.read())
    return samples, info.value


def gray_image(value: int, size: tuple[int, int] = (40, 30)) -> np.ndarray:
    return np.full((size[1], size[0]), value, np.uint8)


# --- UVC camera ---------------------------------------------------------------------------------


def test_uvc_reads_every_frame_of_a_video_then_disconnects(tmp_path):
    video = write_video(tmp_path / "clip.avi")
    camera = create_device({"driver": "uvc", "device": str(video), "max_failed_reads": 2})
    assert isinstance(camera, UvcCamera)
    with camera:
        assert camera.actual_size == FRAME_SIZE
        samples, error = read_until_disconnected(camera)

    assert len(samples) == 10
    for i, sample in enumerate(samples):
        assert sample.image.shape == (240, 320, 3) and sample.image.dtype == np.uint8
        assert abs(float(np.median(sample.image)) - frame_value(i)) <= 6
        assert sample.meta == {"frame_index": i, "device": str(video)}
        assert sample.timestamp_s > 0
    assert "stopped delivering frames" in error.message and "after 10 frames" in error.message
    assert error.device == str(video)


def test_uvc_truncated_video_gives_some_frames_then_disconnects(tmp_path):
    video = write_video(tmp_path / "clip.avi")
    data = video.read_bytes()
    truncated = tmp_path / "half.avi"
    truncated.write_bytes(data[: len(data) // 2])

    with create_device({"driver": "uvc", "device": str(truncated), "max_failed_reads": 2}) as camera:
        samples, error = read_until_disconnected(camera)

    assert 0 < len(samples) < 10
    assert abs(float(np.median(samples[0].image)) - frame_value(0)) <= 6
    assert f"after {len(samples)} frames" in error.message


def test_uvc_missing_device_names_it():
    camera = create_device({"driver": "uvc", "device": "/dev/video99", "max_failed_reads": 2})
    with pytest.raises(DeviceError) as info:
        camera.open()
    assert not isinstance(info.value, DeviceDisconnected)
    assert "/dev/video99" in str(info.value)
    assert "could not open camera /dev/video99: no such device" in info.value.message
    assert "plugged in" in info.value.message
    camera.close()
    camera.close()


def test_uvc_missing_file_names_it(tmp_path):
    missing = tmp_path / "nope.avi"
    with pytest.raises(DeviceError, match="no such file") as info:
        create_device({"driver": "uvc", "device": str(missing)}).open()
    assert info.value.device == str(missing)


def test_uvc_index_is_shown_as_device_path():
    assert UvcCamera(3).name == ("/dev/video3" if sys.platform.startswith("linux") else "3")
    assert UvcCamera("3").device == 3


def test_uvc_warns_when_resolution_differs(tmp_path):
    video = write_video(tmp_path / "clip.avi", frames=2)
    camera = UvcCamera(str(video), width=1280, height=720, max_failed_reads=2)
    assert camera.size_warning is None
    camera.open()
    try:
        assert camera.actual_size == FRAME_SIZE
        assert camera.size_warning == "asked 1280x720 but the camera gives 320x240"
        assert "320x240" in camera.describe() and "warning" in camera.describe()
    finally:
        camera.close()
        camera.close()


def test_uvc_no_warning_when_resolution_matches(tmp_path):
    video = write_video(tmp_path / "clip.avi", frames=2)
    with UvcCamera(str(video), width=320, height=240, fourcc=None) as camera:
        assert camera.size_warning is None
        assert camera.describe() == f"uvc {video} 320x240"


def test_uvc_read_before_open_and_bad_settings():
    with pytest.raises(DeviceError, match="not open"):
        UvcCamera("/dev/video99").read()
    with pytest.raises(DeviceError, match="fourcc"):
        create_device({"driver": "uvc", "fourcc": "MJPEG"})
    with pytest.raises(DeviceError, match="bad settings"):
        create_device({"driver": "uvc", "resolution": "720p"})


# --- image folder -------------------------------------------------------------------------------


def test_natural_key_orders_numbers_by_value():
    names = ["img10.png", "img2.png", "IMG1.png", "img2b.png", "a.png"]
    assert sorted(names, key=natural_key) == ["a.png", "IMG1.png", "img2.png", "img2b.png", "img10.png"]


def test_folder_reads_in_natural_order_then_ends(tmp_path):
    for i in (10, 2, 1):
        cv2.imwrite(str(tmp_path / f"img{i}.png"), gray_image(i))
    (tmp_path / "notes.txt").write_text("not an image")
    cv2.imwrite(str(tmp_path / "upper.JPG"), gray_image(200))

    with create_device({"driver": "folder", "path": str(tmp_path), "pattern": "img*"}) as folder:
        assert isinstance(folder, ImageFolder)
        assert [p.name for p in folder.files] == ["img1.png", "img2.png", "img10.png"]
        samples, error = read_until_disconnected(folder)

    assert [s.meta for s in samples] == [
        {"source": "img1.png", "frame_index": 0},
        {"source": "img2.png", "frame_index": 1},
        {"source": "img10.png", "frame_index": 2},
    ]
    assert [int(s.image[0, 0, 0]) for s in samples] == [1, 2, 10]
    assert samples[0].image.shape == (30, 40, 3)
    assert error.message == "end of folder after 3 images"


def test_folder_accepts_all_extensions_case_insensitively(tmp_path):
    for i, ext in enumerate((".png", ".JPG", ".jpeg", ".bmp", ".tif", ".TIFF", ".pgm", ".ppm")):
        image = gray_image(100) if ext == ".pgm" else cv2.cvtColor(gray_image(100), cv2.COLOR_GRAY2BGR)
        assert cv2.imwrite(str(tmp_path / f"f{i}{ext}"), image)
    folder = ImageFolder(str(tmp_path))
    folder.open()
    assert len(folder.files) == 8
    assert all(folder.read().image.shape == (30, 40, 3) for _ in range(8))
    assert folder.describe() == f"folder {tmp_path} (8 images)"


def test_folder_loops(tmp_path):
    for i in (1, 2):
        cv2.imwrite(str(tmp_path / f"{i}.png"), gray_image(i))
    with create_device({"driver": "folder", "path": str(tmp_path), "loop": True}) as folder:
        sources = [folder.read().meta["source"] for _ in range(5)]
    assert sources == ["1.png", "2.png", "1.png", "2.png", "1.png"]


def test_folder_corrupt_file_is_reported_and_stream_continues(tmp_path):
    cv2.imwrite(str(tmp_path / "img1.png"), gray_image(1))
    (tmp_path / "img2.png").write_text("this is not a png")
    cv2.imwrite(str(tmp_path / "img3.png"), gray_image(3))

    with create_device({"driver": "folder", "path": str(tmp_path)}) as folder:
        assert folder.read().meta["source"] == "img1.png"
        with pytest.raises(InputError) as info:
            folder.read()
        assert info.value.message.startswith("img2.png: not a readable image")
        assert info.value.input == str(tmp_path / "img2.png")
        sample = folder.read()
        assert sample.meta == {"source": "img3.png", "frame_index": 2}
        with pytest.raises(DeviceDisconnected, match="after 3 images"):
            folder.read()


def test_folder_missing_or_empty_names_the_folder(tmp_path):
    missing = tmp_path / "missing"
    with pytest.raises(DeviceError, match="does not exist") as info:
        create_device({"driver": "folder", "path": str(missing)}).open()
    assert info.value.device == str(missing)

    (tmp_path / "readme.txt").write_text("no images here")
    with pytest.raises(DeviceError) as info:
        create_device({"driver": "folder", "path": str(tmp_path)}).open()
    assert str(tmp_path) in info.value.message
    assert "holds no images" in info.value.message and ".png" in info.value.message and ".tiff" in info.value.message


def test_folder_read_before_open(tmp_path):
    with pytest.raises(DeviceError, match="not open"):
        ImageFolder(str(tmp_path)).read()


# --- image I/O ----------------------------------------------------------------------------------


def test_read_image_color_and_grayscale():
    color = read_image(CHESSBOARD_JPEG)
    gray = read_image(CHESSBOARD_JPEG, grayscale=True)
    assert color.ndim == 3 and color.shape[2] == 3 and color.dtype == np.uint8
    assert gray.shape == color.shape[:2]


def test_truncated_jpeg_rejected(tmp_path):
    data = CHESSBOARD_JPEG.read_bytes()
    truncated = tmp_path / "left01_cut.jpg"
    truncated.write_bytes(data[: int(len(data) * 0.6)])
    with pytest.raises(InputError) as info:
        read_image(truncated)
    assert info.value.message.startswith("left01_cut.jpg: not a readable image")
    assert "truncated" in info.value.message
    assert info.value.input == str(truncated)


def test_jpeg_with_trailing_padding_accepted(tmp_path):
    padded = tmp_path / "padded.jpg"
    padded.write_bytes(CHESSBOARD_JPEG.read_bytes() + b"\x00\x00\n")
    assert read_image(padded).shape == read_image(CHESSBOARD_JPEG).shape


def test_truncated_png_rejected(tmp_path):
    data = encode_png(read_image(CHESSBOARD_JPEG))
    truncated = tmp_path / "board.png"
    truncated.write_bytes(data[: len(data) - 20])
    with pytest.raises(InputError, match=r"^board\.png: not a readable image"):
        read_image(truncated)


@pytest.mark.parametrize(
    ("name", "content"),
    [("x.png", b"just some text, not a picture\n"), ("empty.jpg", b""), ("noise.bmp", bytes(range(256)))],
)
def test_non_images_rejected(tmp_path, name, content):
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(InputError) as info:
        read_image(path)
    assert info.value.message.startswith(f"{name}: not a readable image (expected PNG/JPEG")
    assert info.value.input == str(path)


def test_missing_file_rejected(tmp_path):
    with pytest.raises(InputError, match="nope.png: cannot read file"):
        read_image(tmp_path / "nope.png")


def test_decode_image_bytes_same_checks():
    data = CHESSBOARD_JPEG.read_bytes()
    assert decode_image_bytes(data, "upload.jpg", grayscale=True).ndim == 2
    with pytest.raises(InputError) as info:
        decode_image_bytes(data[: len(data) // 2], "upload.jpg")
    assert info.value.message.startswith("upload.jpg: not a readable image")
    assert info.value.input == "upload.jpg"


def test_encode_round_trip():
    image = np.zeros((20, 30, 3), np.uint8)
    image[5:15, 10:20] = (0, 128, 255)
    assert np.array_equal(decode_image_bytes(encode_png(image), "a.png"), image)
    jpeg = encode_jpeg(image, quality=95)
    assert jpeg.startswith(b"\xff\xd8") and jpeg.endswith(b"\xff\xd9")
    assert np.abs(decode_image_bytes(jpeg, "a.jpg")[10, 15].astype(int) - (0, 128, 255)).max() < 10
    assert len(encode_jpeg(image, quality=10)) < len(jpeg)
