"""The render demo writes its picture readable like every other output."""
from __future__ import annotations

import stat

import numpy as np
from PIL import Image

from renderer import demo


def test_demo_png_follows_the_umask(tmp_path, umask_022):
    demo.main(["--out", str(tmp_path / "out"), "--resolution", "8", "--image-size", "6"])
    png = tmp_path / "out" / "render_demo.png"
    assert stat.S_IMODE(png.stat().st_mode) == 0o644
    assert np.asarray(Image.open(png)).shape == (3 * 6, 4 * 6, 3)
    assert [p.name for p in png.parent.iterdir()] == ["render_demo.png"]  # no temporary left behind
