"""A headless screenshot of the bundled recording in the real Rerun viewer is not blank."""

import numpy as np
from click.testing import CliRunner

from trackreplay.face.cli import main


def test_headless_screenshot_is_not_blank(tmp_path, demo_mcap, monkeypatch):
    monkeypatch.chdir(tmp_path)
    runner = CliRunner()
    res = runner.invoke(main, [str(demo_mcap), "--out", str(tmp_path / "o" / "t.mcap")])
    assert res.exit_code == 0, res.output
    png = tmp_path / "shot.png"
    res = runner.invoke(main, ["view", str(tmp_path / "o" / "t.rrd"), "--screenshot", str(png)])
    assert res.exit_code == 0, res.output
    from PIL import Image

    img = np.asarray(Image.open(png).convert("RGB")).astype(float)
    assert img.shape[0] >= 600 and img.shape[1] >= 1000
    # a blank or single-colour frame has (almost) no spread; the viewer with plots has plenty
    assert img.std() > 10
    assert len(np.unique(img.reshape(-1, 3)[::97], axis=0)) > 50
