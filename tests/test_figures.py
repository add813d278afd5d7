"""Every report figure a replay writes is rendered and not blank (image statistics of each PNG).

How the figures were looked at: by eye, one per family, in the session that wrote them; this
test keeps them from degrading into empty axes silently.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from matplotlib.image import imread

from pipeline.face.cli import main

DATA = Path(__file__).resolve().parents[1] / "data"
DEMOS = sorted(p.name for p in DATA.glob("*.mcap"))


@pytest.mark.parametrize("demo", DEMOS)
def test_every_report_figure_is_rendered_and_not_blank(tmp_path, demo):
    out = tmp_path / "o"
    res = CliRunner().invoke(main, [str(DATA / demo), "--no-rrd", "--out", str(out / "tracks.mcap"), "-q"])
    assert res.exit_code == 0, res.output
    pngs = sorted(out.glob("*.png"))
    assert pngs, f"{demo}: no report figure"
    for png in pngs:
        img = imread(png)[..., :3]
        h, w = img.shape[:2]
        assert h >= 200 and w >= 300, (png.name, img.shape)
        ink = np.mean(np.abs(img - 1.0).sum(axis=-1) > 0.1)  # pixels that are not (near) white
        colours = np.unique((img.reshape(-1, 3) * 255).astype(np.uint8), axis=0).shape[0]
        assert 0.01 < ink < 0.9, (png.name, ink)
        assert colours > 20, (png.name, colours)  # axes, text and data in several colours
