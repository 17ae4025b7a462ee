import pytest

from sianms_cli.synth.generate import SynthConfig, synthesize

TINY = dict(scenes=2, image_scale=0.1, scene_seconds=1.5, seed=3)


def tiny_dataset(path, **overrides):
    """A 2-scene, 3-keyframe dataset with 160x90 images: every table and file, in seconds."""
    return synthesize(path, SynthConfig(**{**TINY, **overrides}), progress=False)


@pytest.fixture
def make_tiny():
    return tiny_dataset


@pytest.fixture(scope="session")
def tiny_dataroot(tmp_path_factory):
    return tiny_dataset(tmp_path_factory.mktemp("synth") / "mini")
