"""bench/loader.py: a dataroot it cannot load is one error line, not a parent waiting forever on its child."""

import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "bench" / "loader.py"


def test_a_dataroot_without_the_version_is_one_error_line(tmp_path):
    result = subprocess.run([sys.executable, str(SCRIPT), str(tmp_path), "v1.0-mini"], capture_output=True,
                            text=True, timeout=120)
    assert (result.returncode, result.stdout) == (2, "")
    assert result.stderr == (f"error: {tmp_path / 'v1.0-mini'}: version folder not found "
                             "(expected <dataroot>/<version>/)\n")
