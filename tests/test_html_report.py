"""`report SYSTEM DIR --html OUT.html`: one self-contained page (no network), opened in a real headless browser (Debian's
chromium, installed by `make browser`; the test skips with the reason where it is absent): it loads without a console
error, every session's figure is drawn, and the screenshot holds the curves."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from fusegraph.cli import main

BROWSER = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")


@pytest.fixture(scope="module")
def page(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("html")
    for seed in (0, 1):
        assert main(["simulate", "attitude9", "--seed", str(seed), "--duration", "20", "--out", str(root / "s" / f"seed{seed}")]) == 0
    out = root / "report.html"
    assert main(["report", "attitude9", str(root / "s"), "--solvers", "online,batch", "--html", str(out)]) == 0
    return root, out


def test_the_page_stands_alone(page: tuple[Path, Path]) -> None:
    from plotly.offline import get_plotlyjs

    text = page[1].read_text()
    bundle = get_plotlyjs()
    assert bundle in text  # plotly's script inlined...
    ours = text.replace(bundle, "")
    assert "src=" not in ours and "http" not in ours  # ...and nothing else fetched: the page works offline
    assert text.count("class=\"plotly-graph-div\"") == 2  # a figure per session
    assert "total_deg" in text and "seed0" in text and "seed1" in text  # the table and the sessions


@pytest.mark.skipif(BROWSER is None, reason="no chromium on this machine (`make browser` installs Debian's; .ci/run does)")
def test_the_page_loads_in_a_headless_browser_without_console_errors_and_draws_the_curves(page: tuple[Path, Path]) -> None:
    root, out = page
    flags = [str(BROWSER), "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", "--enable-logging=stderr", "--v=0",
             "--virtual-time-budget=10000", "--window-size=1300,1400"]
    dom = subprocess.run([*flags, "--dump-dom", out.as_uri()], capture_output=True, text=True, timeout=120)
    console = [line for line in dom.stderr.splitlines() if "CONSOLE" in line]
    assert not console, console  # the page logs nothing: no error, no warning
    assert dom.stdout.count("class=\"main-svg\"") >= 2, "plotly drew no figure"
    shot = root / "shot.png"
    subprocess.run([*flags, f"--screenshot={shot}", out.as_uri()], capture_output=True, timeout=120, check=True)
    from PIL import Image

    pixels = np.asarray(Image.open(shot).convert("RGB"), dtype=int)
    lower = pixels[500:, :, :]  # below the table: the first session's figure
    online_blue = np.all(np.abs(lower - [0x1F, 0x77, 0xB4]) < 40, axis=2).sum()
    batch_red = np.all(np.abs(lower - [0xD6, 0x27, 0x28]) < 40, axis=2).sum()
    assert online_blue > 200 and batch_red > 200, (online_blue, batch_red)  # both solvers' curves are on the screen
