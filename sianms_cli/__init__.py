"""sianms: multi-camera 3D object detection research on nuScenes-format data."""

__version__ = "0.1.0"

from sianms_cli.kernel_cache import choose_kernel_cache  # noqa: E402  before any module loads numba

choose_kernel_cache()
