"""How the ego drives through each scene: straight, turning, changing lanes.

nuScenes is mostly go-straight driving (73.9 % of its planning scenarios, Li et al., arXiv
2312.03031, by a rule the sources found do not state; 86.7 % of val's 5,119 key frames with
3 s ahead by the command rule below, a third-party count), and the ego's turns are what swing
objects across camera seams. Two rules, on the
ego pose of each sample's LIDAR_TOP key frame:

- a keyframe's driving command, as the nuScenes open-loop planning benchmark derives it (VAD's
  data converter): the ego position 3 s (6 keyframes at 2 Hz) ahead, in the keyframe's ego
  frame, lies at least 2 m to the left or right: "turn"; otherwise "go straight". A lane change
  (≈ 3.5 m sideways in 3–5 s) or a turn crosses 2 m; a gentle curve at city speed does not
  (10 m/s on a 500 m radius drifts 0.9 m in 3 s). Keyframes without one 3 s ahead in their
  scene have no command.
- a scene turns when its ego heading spans more than 30° over the scene: every intersection
  turn (≈ 90°) passes, a curving street over a 20 s scene rarely does, and pose noise is far
  below it.

A scene is "not simply going straight" when it turns or any of its keyframes is commanded
to turn.
"""

from __future__ import annotations

import numpy as np

from sianms_cli.geometry.quaternion import quat_to_matrix
from sianms_cli.nuscenes.loader import NuScenesDB
from sianms_cli.nuscenes.overlap import lidar_ego_poses

COMMAND_HORIZON_KEYFRAMES = 6  # 3 s at 2 Hz (VAD's fut_ts)
COMMAND_LATERAL_M = 2.0  # VAD's go-straight band, metres
TURN_DEGREES = 30.0


def ego_motion(db: NuScenesDB) -> dict:
    """Go-straight keyframes and turning scenes of a dataset (see the module docstring)."""
    samples = db.table("sample")
    rotation, translation, found = lidar_ego_poses(db, np.arange(len(samples)))
    rows = np.flatnonzero(found)
    scene = samples.rows("scene_token")[rows]
    order = np.lexsort((samples.column("timestamp")[rows], scene))
    rows, scene = rows[order], scene[order]
    heading_matrix = quat_to_matrix(rotation[rows])
    lateral, has_command = lateral_offsets(heading_matrix, translation[rows], scene, COMMAND_HORIZON_KEYFRAMES)
    turn_command = has_command & (np.abs(lateral) >= COMMAND_LATERAL_M)
    span = heading_spans(np.arctan2(heading_matrix[:, 1, 0], heading_matrix[:, 0, 0]), scene)
    scenes, scene_index = np.unique(scene, return_inverse=True)
    turning = np.degrees(span) > TURN_DEGREES
    commanded = np.bincount(scene_index, weights=turn_command, minlength=len(scenes)) > 0
    return {
        "keyframes_with_command": int(has_command.sum()),
        "share_keyframes_go_straight": _share(~turn_command[has_command]),
        "scenes": len(scenes),
        "share_scenes_turning": _share(turning),
        "share_scenes_not_straight": _share(turning | commanded),
        "scene_heading_span_degrees": {
            "median": float(np.degrees(np.median(span))) if len(span) else None,
            "max": float(np.degrees(np.max(span))) if len(span) else None,
        },
    }


def lateral_offsets(rotation: np.ndarray, translation: np.ndarray, scene: np.ndarray,
                    horizon: int) -> tuple[np.ndarray, np.ndarray]:
    """Sideways offset (ego +y, left) of the position ``horizon`` keyframes later in the scene.

    Args:
        rotation, translation: (K, 3, 3), (K, 3) ego poses, ordered by (scene, time).
        scene: (K,) scene of each keyframe.
        horizon: keyframes ahead.

    Returns:
        ``(lateral (K,) metres, has (K,) bool)``; 0 and False where the scene ends sooner.
    """
    later = np.arange(len(scene)) + horizon
    has = later < len(scene)
    has[has] = scene[later[has]] == scene[has]
    later = np.where(has, later, np.arange(len(scene)))
    offset = np.einsum("kji,kj->ki", rotation, translation[later] - translation)
    return np.where(has, offset[:, 1], 0.0), has


def heading_spans(yaw: np.ndarray, scene: np.ndarray) -> np.ndarray:
    """(scenes,) max − min of the unwrapped heading over each scene, radians.

    Args:
        yaw: (K,) headings ordered by (scene, time).
        scene: (K,) scene of each keyframe, grouped (equal values adjacent).
    """
    if len(yaw) == 0:
        return np.zeros(0)
    same = scene[1:] == scene[:-1]
    step = np.where(same, np.angle(np.exp(1j * np.diff(yaw))), 0.0)
    unwrapped = np.r_[0.0, np.cumsum(step)]
    starts = np.flatnonzero(np.r_[True, ~same])
    return np.maximum.reduceat(unwrapped, starts) - np.minimum.reduceat(unwrapped, starts)


def _share(mask: np.ndarray) -> float | None:
    return float(np.mean(mask)) if len(mask) else None
