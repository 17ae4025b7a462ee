import numpy as np
import pytest

from sianms_cli.geometry.quaternion import quat_to_matrix, yaw_to_quat
from sianms_cli.nuscenes.loader import NuScenesDB
from sianms_cli.reporting.ego_motion import ego_motion, heading_spans, lateral_offsets


def _poses(xy, yaw):
    xy = np.asarray(xy, dtype=float)
    return quat_to_matrix(yaw_to_quat(np.asarray(yaw, dtype=float))), np.c_[xy, np.zeros(len(xy))]


def test_lateral_offset_is_the_later_position_sideways_in_the_current_ego_frame():
    # Heading +y (yaw 90 deg): a point 3 m further along -x lies 3 m to the ego's left.
    rotation, translation = _poses([[0, 0], [-3, 5], [7, 7]], [np.pi / 2] * 3)
    lateral, has = lateral_offsets(rotation, translation, np.array([0, 0, 1]), horizon=1)
    assert has.tolist() == [True, False, False]
    assert lateral == pytest.approx([3.0, 0.0, 0.0])


def test_a_lane_change_and_a_straight_drive():
    x = np.arange(8) * 5.0
    lane_change = np.clip((np.arange(8) - 2) * 1.0, 0, 3.5)
    rotation, translation = _poses(np.r_[np.c_[x, np.zeros(8)], np.c_[x, lane_change]], np.zeros(16))
    lateral, has = lateral_offsets(rotation, translation, np.repeat([0, 1], 8), horizon=6)
    assert has.tolist() == ([True] * 2 + [False] * 6) * 2
    assert np.abs(lateral[:2]).max() == 0 and lateral[8:10] == pytest.approx([3.5, 3.5])


def test_heading_spans_unwrap_across_minus_pi_and_reset_per_scene():
    yaw = np.radians([170.0, 179.0, -175.0, -170.0, 0.0, 10.0, -25.0])
    spans = heading_spans(yaw, np.array([0, 0, 0, 0, 1, 1, 1]))
    assert np.degrees(spans) == pytest.approx([20.0, 35.0])
    assert heading_spans(np.zeros(0), np.zeros(0, dtype=int)).shape == (0,)


def test_shares_on_a_synthetic_dataroot_are_consistent(tiny_dataroot):
    motion = ego_motion(NuScenesDB(tiny_dataroot, "v1.0-mini"))
    assert motion["scenes"] == 2
    assert motion["share_scenes_turning"] <= motion["share_scenes_not_straight"]
    # 3 keyframes per scene: none has one 3 s ahead.
    assert motion["keyframes_with_command"] == 0 and motion["share_keyframes_go_straight"] is None
