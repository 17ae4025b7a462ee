"""report.html in a real browser: headless Chromium renders it offline and Table I is in the DOM.

Opt-in by marker (``pytest -m browser``) and skipped where no ``chromium`` or
``chromium-browser`` binary is on PATH.
"""

from __future__ import annotations

import shutil
import subprocess

import pytest

from sianms_cli.reporting.report import ReportConfig, run

pytestmark = pytest.mark.browser


def _chromium() -> str:
    for name in ("chromium", "chromium-browser"):
        found = shutil.which(name)
        if found:
            return found
    pytest.skip("no chromium or chromium-browser on PATH")


def test_chromium_renders_table_i(tmp_path, eval_folders):
    browser = _chromium()
    evaluation = eval_folders.make_eval(tmp_path / "eval", details=True)
    report = run(ReportConfig(eval=str(evaluation)))
    done = subprocess.run([browser, "--headless", "--no-sandbox", "--disable-gpu", "--dump-dom",
                           report.html.resolve().as_uri()], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    dom = done.stdout
    assert '<table id="table-i">' in dom
    assert ('<td class="label">All</td><td class="label">vanilla</td><td>31.2</td><td>0.612</td><td>24.6</td>'
            "<td>1.381</td>") in dom
    assert dom.count('src="data:image/png;base64,') == 3
