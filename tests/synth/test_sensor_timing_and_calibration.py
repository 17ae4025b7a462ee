import numpy as np
import pytest

from sianms_cli.geometry.quaternion import quat_multiply, quat_to_matrix
from sianms_cli.synth import nuscenes_rig as rig
from sianms_cli.synth.nuscenes_rig import (
    CALIBRATION_RESIDUAL_DEG,
    CALIBRATION_RESIDUAL_M,
    CAMERA_TRIGGER_OFFSET_US,
    LIDAR_HZ,
    RESIDUAL_TRUNCATION,
    lidar_column_seconds,
    lidar_start_azimuth,
    true_calibration,
)

RIGS = [rig.normalised_rig(rig.RIG_BOSTON), rig.normalised_rig(rig.RIG_SINGAPORE)]


def residual(written, true):
    """Rotation angle (degrees) and per-axis translation (m) from the written to the true calibration."""
    conjugate = np.asarray(written.rotation) * [1, -1, -1, -1]
    relative = quat_multiply(conjugate, true.rotation)
    angle = np.degrees(2 * np.arccos(np.clip(abs(relative[0]), 0.0, 1.0)))
    return angle, np.asarray(true.translation) - np.asarray(written.translation)


def test_calibration_residuals_stay_within_their_stated_bounds():
    rng = np.random.default_rng(0)
    angles, offsets = [], []
    for _ in range(200):
        for calibration in RIGS[0]:
            true = true_calibration(calibration, rng)
            angle, offset = residual(calibration, true)
            angles.append(angle)
            offsets.append(offset)
            assert true.focal == calibration.focal and true.principal == calibration.principal
    angles, offsets = np.array(angles), np.array(offsets)
    assert angles.max() <= np.sqrt(3) * RESIDUAL_TRUNCATION * CALIBRATION_RESIDUAL_DEG + 1e-9
    assert np.abs(offsets).max() <= RESIDUAL_TRUNCATION * CALIBRATION_RESIDUAL_M + 1e-12
    # Not zero: tenths of a degree and about a centimetre, as the module states.
    assert 0.1 < np.median(angles) < 0.3 and 0.005 < np.median(np.linalg.norm(offsets, axis=1)) < 0.02


def test_calibration_residuals_are_deterministic():
    a = [true_calibration(c, np.random.default_rng(3)) for c in RIGS[1]]
    b = [true_calibration(c, np.random.default_rng(3)) for c in RIGS[1]]
    assert a == b and a != list(RIGS[1])


def test_columns_fire_over_one_sweep_ending_at_its_timestamp():
    seconds = lidar_column_seconds(1084)
    assert seconds[-1] == 0.0
    np.testing.assert_allclose(np.diff(seconds), 1 / (1084 * LIDAR_HZ))
    assert seconds[0] == pytest.approx(-1 / LIDAR_HZ + 1 / (1084 * LIDAR_HZ))


@pytest.mark.parametrize("calibrations", RIGS)
def test_the_beam_crosses_cam_front_when_it_is_triggered(calibrations):
    by_channel = {c.channel: c for c in calibrations}
    steps = 1084
    start = lidar_start_azimuth(by_channel["LIDAR_TOP"], by_channel["CAM_FRONT"], steps)
    seconds = lidar_column_seconds(steps)
    trigger = CAMERA_TRIGGER_OFFSET_US["CAM_FRONT"] / 1e6
    column = (trigger - seconds[0]) * LIDAR_HZ * steps  # fractional column at the trigger time
    azimuth = start - 2 * np.pi * column / steps
    beam_ego = quat_to_matrix(np.asarray(by_channel["LIDAR_TOP"].rotation)) @ [np.cos(azimuth), np.sin(azimuth), 0.0]
    axis_ego = quat_to_matrix(np.asarray(by_channel["CAM_FRONT"].rotation))[:, 2]
    heading = np.arctan2(beam_ego[1], beam_ego[0]) - np.arctan2(axis_ego[1], axis_ego[0])
    # Within a fifth of a column: the LIDAR is tilted about a degree, so its level beam is not the ego's.
    assert abs(np.angle(np.exp(1j * heading))) < 0.2 * 2 * np.pi / steps
