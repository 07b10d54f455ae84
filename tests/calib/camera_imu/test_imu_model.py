"""The IMU's ``scale-misalignment`` model: the gyro's and accelerometer's residual gradients (what the normal
equations assemble) against central differences of their cost, by every shared parameter and by spline
coefficients; and the model's parameters stepped as the solver steps them."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from backend.calib.camera_imu import imu_model, normal_equations
from backend.calib.camera_imu.imu_model import ImuIntrinsics
from backend.calib.camera_imu.spline import UniformSpline
from backend.calib.camera_imu.trajectory import INTRINSICS, VALUES, TrajectoryState, imu_residuals
from backend.core.imu import ImuSamples
from backend.core.transforms import make_T

STEP = 1e-6


def _state(rng: np.random.Generator, intrinsics: ImuIntrinsics | None) -> TrajectoryState:
    spline = UniformSpline(0.0, 2.0, 0.05)
    coefficients = rng.normal(0.0, 0.3, (spline.n_coefficients, VALUES))
    T_cam_imu = make_T(Rotation.from_rotvec(rng.normal(0, 1, 3)).as_matrix(), rng.normal(0, 0.05, 3))
    return TrajectoryState(spline, coefficients, Rotation.from_rotvec([0.3, -0.2, 0.1]).as_matrix(), T_cam_imu, 0.01,
                           rng.normal(0, 0.01, 3), rng.normal(0, 0.1, 3), np.array([0.5, 9.7, -1.0]), intrinsics)


def _samples(rng: np.random.Generator) -> ImuSamples:
    t = np.sort(rng.uniform(0.1, 1.9, 60))
    return ImuSamples(t, rng.normal(0, 1.0, (60, 3)), rng.normal(0, 5.0, (60, 3)) + [0, 0, 9.8])


@pytest.mark.parametrize("model", imu_model.IMU_MODELS)
@pytest.mark.parametrize("kind", ["gyro", "accel"])
def test_gradients_match_central_differences(model: str, kind: str) -> None:
    rng = np.random.default_rng(7)
    misaligned = ImuIntrinsics(np.eye(3) + np.tril(rng.normal(0, 0.01, (3, 3))),
                               np.eye(3) + np.tril(rng.normal(0, 0.01, (3, 3))),
                               Rotation.from_rotvec(rng.normal(0, 0.01, 3)).as_matrix(), rng.normal(0, 1e-3, (3, 3)))
    state = _state(rng, misaligned if model == "scale-misalignment" else None)
    imu = _samples(rng)
    which = 0 if kind == "gyro" else 1

    def cost(moved: TrajectoryState) -> float:
        residuals = imu_residuals(moved, imu, 0.01, 0.1, with_jacobian=False)[which].residuals
        return 0.5 * float(residuals @ residuals)

    equations = normal_equations.assemble([imu_residuals(state, imu, 0.01, 0.1)[which]], state.spline)
    n = state.coefficients.size
    assert len(equations.g_s) == state.n_shared == (39 if model == "scale-misalignment" else 15)
    coefficients = rng.choice(n, 12, replace=False)
    for index, analytic in [*((n + k, equations.g_s[k]) for k in range(state.n_shared)),
                            *((k, equations.g_c[k]) for k in coefficients)]:
        step = np.zeros(n + state.n_shared)
        step[index] = STEP
        numeric = (cost(state.stepped(step)) - cost(state.stepped(-step))) / (2 * STEP)
        scale = max(np.abs(equations.g_s).max(), 1.0)
        assert abs(numeric - analytic) < 1e-5 * scale, (index, numeric, analytic)


def test_a_step_moves_each_part_of_the_model_in_the_documented_order() -> None:
    moved = ImuIntrinsics.ideal().stepped(np.arange(1, imu_model.SIZE + 1) * 1e-3)
    assert moved.accel_M[0, 1] == 0.0 and moved.accel_M[2, 2] == pytest.approx(1.006)  # lower triangle, row by row
    assert moved.gyro_M[1, 0] == pytest.approx(0.008)
    assert np.allclose(Rotation.from_matrix(moved.R_gyro_accel).as_rotvec(), [0.013, 0.014, 0.015])
    assert moved.g_sensitivity[2, 1] == pytest.approx(0.023)  # entries 16-24, row by row
    assert INTRINSICS.stop - INTRINSICS.start == imu_model.SIZE
