import numpy as np
import pytest

from sianms_cli.synth.world import SCENE_SECONDS


def _track_yaws(plan, rows: np.ndarray, dt: float = 1e-3) -> list[np.ndarray]:
    """Checks, every 0.25 s of the scene, that finite differences of road users ``rows``'
    positions give their stated speed and that a moving one points where it goes (against its
    path for oncoming traffic, whose path runs backwards); returns their yaws at each check."""
    yaws = []
    for t in np.arange(0.0, SCENE_SECONDS, 0.25):
        center, yaw, speed = plan.agents.pose(plan.route, t)
        later, _, _ = plan.agents.pose(plan.route, t + dt)
        step = later[rows, :2] - center[rows, :2]
        np.testing.assert_allclose(np.hypot(*step.T) / dt, speed[rows], atol=2e-3)
        going = speed[rows] > 0.5
        motion = np.arctan2(step[going, 1], step[going, 0])
        assert np.all(np.abs(np.angle(np.exp(1j * (motion - yaw[rows][going])))) < 0.01)
        yaws.append(yaw[rows])
    return yaws


@pytest.fixture
def track_yaws():
    """:func:`_track_yaws`: a plan's tracks checked for consistent speed and heading."""
    return _track_yaws
