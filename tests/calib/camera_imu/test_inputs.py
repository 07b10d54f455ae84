"""Bad camera-IMU input: IMU streams and detection files that cannot be used get a message naming the file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from backend.calib.camera_imu.observations import check_board_points, detect_image_folder, read_detections_csv
from backend.core.errors import InputError
from backend.devices.imu_csv import read_imu_csv
from backend.sim.camera_imu import BOARD, simulate_recording, write_images


def _write_imu(path: Path, t_ns: np.ndarray, values: np.ndarray) -> Path:
    rows = "\n".join(f"{int(t)},{','.join(f'{v:.6f}' for v in row)}" for t, row in zip(t_ns, values, strict=True))
    path.write_text("#ts,wx,wy,wz,ax,ay,az\n" + rows + "\n")
    return path


def _samples(n: int = 400) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    return np.arange(n) * 5_000_000 + 10**18, rng.normal(0, 0.5, (n, 6))


def test_time_stamps_running_backwards_are_refused_by_sample(tmp_path: Path) -> None:
    t_ns, values = _samples()
    t_ns[200] = t_ns[150]
    with pytest.raises(InputError, match=r"imu.csv: time stamps run backwards or repeat at sample 201") as error:
        read_imu_csv(_write_imu(tmp_path / "imu.csv", t_ns, values), "imu.csv")
    assert error.value.input == "imu.csv"


def test_gaps_and_a_saturated_gyro_are_warned_and_the_samples_kept(tmp_path: Path) -> None:
    t_ns, values = _samples()
    t_ns[300:] += 400_000_000  # a 0.4 s gap
    values[::10, 0] = 8.7  # the gyro's x axis clipped at its range in a tenth of the samples
    samples, warnings = read_imu_csv(_write_imu(tmp_path / "imu.csv", t_ns, values), "imu.csv")
    assert len(samples.t_s) == 400
    assert any("1 gap(s)" in w and "405 ms" in w for w in warnings), warnings
    assert any("gyro's x axis sits at 8.7 rad/s in 10.0% of the samples: saturated" in w for w in warnings), warnings
    assert samples.saturated.sum() == 40


def test_detections_with_other_columns_are_refused_naming_them(tmp_path: Path) -> None:
    path = tmp_path / "corners.csv"
    path.write_text("time,u,v\n1,2,3\n")
    with pytest.raises(InputError, match=r"corners.csv: the header names the columns time, u, v; expected t_ns, "
                                         r"u_px, v_px, x_m, y_m, z_m, tag_id, corner"):
        read_detections_csv(path, "corners.csv")


def test_detections_of_another_board_are_refused(tmp_path: Path) -> None:
    path = tmp_path / "corners.csv"
    path.write_text("t_ns,u_px,v_px,x_m,y_m,z_m,tag_id,corner\n" + "\n".join(
        f"1000,{u},{u},{x},0,0,0,{i}" for i, (u, x) in enumerate([(10, 0.0), (20, 0.088), (30, 0.1144)])) + "\n")
    observations = read_detections_csv(path, "corners.csv")
    check_board_points(observations, "aprilgrid:6x6:0.088:0.3", "corners.csv")
    with pytest.raises(InputError, match=r"corners.csv: 2 of its 3 distinct board points are not corners of the "
                                         r"board aprilgrid:6x6:0.06:0.3"):
        check_board_points(observations, "aprilgrid:6x6:0.06:0.3", "corners.csv")


def test_a_folder_of_images_gives_the_corners_the_recording_holds(tmp_path: Path) -> None:
    """Rendered frames named by their time stamps: the board found in each at its time, its corners within 0.3 px
    of the simulator's (noisy by 0.3 px themselves)."""
    recording = simulate_recording(duration_s=1.0, pixel_sigma=0.0)
    write_images(recording, tmp_path / "frames", range(3))
    found = detect_image_folder(tmp_path / "frames", BOARD)
    assert np.allclose(found.t_s, recording.observations.t_s[:3], atol=1e-6)
    for frame in range(3):
        truth = recording.observations.subset(np.array([frame]))
        seen = found.subset(np.array([frame]))
        nearest = np.linalg.norm(seen.board_m[:, None] - truth.board_m[None], axis=2).argmin(axis=1)
        assert len(seen.frame) > 40
        assert np.median(np.linalg.norm(seen.pixels_px - truth.pixels_px[nearest], axis=1)) < 0.3


def test_an_image_not_named_by_its_time_is_refused(tmp_path: Path) -> None:
    (tmp_path / "frames").mkdir()
    (tmp_path / "frames" / "left01.png").write_bytes(b"")
    with pytest.raises(InputError, match=r"left01.png: expected the image's time stamp in ns as its name"):
        detect_image_folder(tmp_path / "frames", BOARD)
