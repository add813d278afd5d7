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

from trackreplay.face.cli import main

DATA = Path(__file__).resolve().parents[1] / "data"
DEMOS = sorted(p.name for p in DATA.glob("*.mcap"))


# the trackers each bundled demo must show, by the name its figures label them with
TRACKERS = {
    "radar_tws_demo.mcap": {"fixed", "approximate", "exact", "kalman"},
    "xcorr_crossing_demo.mcap": {"jpda", "jpda_a"},
    "array_crossing_demo.mcap": {"proposed", "ryu"},
    "tdoa_fdoa_demo.mcap": {"joint", "tdoa"},
    "tdoa_fdoa_noise_demo.mcap": {"joint", "tdoa", "fdoa"},
    "colored_imm_demo.mcap": {"kf", "kf_dp", "imm", "mimm_k", "pimm"},
    "colored_circle_demo.mcap": {"kf", "kf_dp", "imm", "mimm_k", "pimm"},
}


def _record_figures(monkeypatch) -> list[dict]:
    """Patch the one exit of every figure to note what each panel shows before it is written."""
    import trackreplay.evaluators.report_plots as rp

    seen, original = [], rp.save_figure

    def noting(fig, path, *args, **kwargs):
        panels = []
        for ax in fig.axes:
            if not ax.get_visible():
                continue
            lines = [(line.get_label(), np.asarray(line.get_xdata(), float), np.asarray(line.get_ydata(), float))
                     for line in ax.get_lines()]
            legend = ax.get_legend()
            panels.append({"xlim": sorted(ax.get_xlim()), "ylim": sorted(ax.get_ylim()), "lines": lines,
                           "log": (ax.get_xscale() == "log", ax.get_yscale() == "log"),
                           "legend": [t.get_text() for t in legend.get_texts()] if legend else []})
        seen.append({"name": Path(path).name, "panels": panels})
        return original(fig, path, *args, **kwargs)

    monkeypatch.setattr(rp, "save_figure", noting)
    return seen


@pytest.fixture(scope="module")
def replayed(tmp_path_factory):
    """``replayed(demo)`` → (output folder, what each figure's panels showed) of one replay of the
    bundled ``demo`` through the command line; each demo is replayed once for both tests below
    (the noting patch only looks at the figures before they are written)."""
    done = {}

    def get(demo: str):
        if demo not in done:
            out = tmp_path_factory.mktemp(demo.split(".")[0]) / "o"
            with pytest.MonkeyPatch.context() as mp:
                seen = _record_figures(mp)
                res = CliRunner().invoke(main, [str(DATA / demo), "--no-rrd", "--out", str(out / "tracks.mcap"), "-q"])
            assert res.exit_code == 0, res.output
            done[demo] = out, seen
        return done[demo]

    return get


@pytest.mark.parametrize("demo", DEMOS)
def test_every_report_figure_is_rendered_and_not_blank(replayed, demo):
    out, _ = replayed(demo)
    pngs = sorted(out.glob("*.png"))
    assert pngs, f"{demo}: no report figure"
    for png in pngs:
        img = imread(png)[..., :3]
        h, w = img.shape[:2]
        assert h >= 200 and w >= 300, (png.name, img.shape)
        ink = np.mean(np.abs(img - 1.0).sum(axis=-1) > 0.1)  # pixels that are not (near) white
        # distinct colours, each RGB triple packed into one integer (np.unique over rows is ~30x slower)
        rgb = (img.reshape(-1, 3) * 255).astype(np.uint8).astype(np.uint32)
        colours = np.unique((rgb[:, 0] << 16) | (rgb[:, 1] << 8) | rgb[:, 2]).size
        assert 0.01 < ink < 0.9, (png.name, ink)
        assert colours > 20, (png.name, colours)  # axes, text and data in several colours


@pytest.mark.parametrize("demo", sorted(TRACKERS))
def test_every_figure_shows_every_tracker_labelled_and_its_data_inside_the_axes(replayed, demo):
    out, seen = replayed(demo)
    names = {f["name"] for f in seen}
    assert "report.png" in names and names <= {p.name for p in out.glob("*.png")}, names
    for fig in seen:
        legends = [label for p in fig["panels"] for label in p["legend"]]
        assert legends, f"{demo} {fig['name']}: no legend"
        if fig["name"] in ("report.png", "consistency.png", "errors.png", "rmse.png", "fig7.png"):
            # every tracker is a labelled series (a label may carry more, e.g. "joint RMSE")
            shown = {t for t in TRACKERS[demo] if any(label.split(":")[0].split(" ")[0] == t for label in legends)}
            assert shown == TRACKERS[demo], (demo, fig["name"], legends)
        for p in fig["panels"]:
            (x0, x1), (y0, y1) = p["xlim"], p["ylim"]
            for label, x, y in p["lines"]:
                ok = np.isfinite(x) & np.isfinite(y)
                # a log axis cannot show zero (e.g. an ANEES of 0 at a start on the truth)
                ok &= (x > 0 if p["log"][0] else True) & (y > 0 if p["log"][1] else True)
                if not ok.any() or label.startswith("_"):
                    continue  # reference lines (axhline/axvline) and empty series
                inside = (x[ok] >= x0) & (x[ok] <= x1) & (y[ok] >= y0) & (y[ok] <= y1)
                # ellipses may be cut by a zoom frame; data series must lie inside the axes
                assert inside.mean() >= (0.5 if "95 %" in label else 1.0), (demo, fig["name"], label, inside.mean())


# --------------------------------------------------------------------------- when figures are drawn


def _pngs(folder: Path) -> set:
    return {p.name for p in folder.glob("*.png")}


def test_figures_none_then_replay_plot_draws_the_same_figures(tmp_path):
    """`--figures none` writes every output but the figures; `replay plot DATA TRACKS` draws,
    from those files alone, the figures a replay draws itself."""
    data = DATA / "radar_tws_demo.mcap"
    runner = CliRunner()
    drawn, bare = tmp_path / "drawn" / "tracks.mcap", tmp_path / "bare" / "tracks.mcap"
    assert runner.invoke(main, [str(data), "--no-rrd", "-q", "--out", str(drawn), "--figures", "now"]).exit_code == 0
    res = runner.invoke(main, [str(data), "--no-rrd", "-q", "--out", str(bare), "--figures", "none"])
    assert res.exit_code == 0 and not _pngs(bare.parent) and "plots:" not in res.output
    res = runner.invoke(main, ["plot", str(data), str(bare), "-q"])
    assert res.exit_code == 0, res.output
    assert _pngs(bare.parent) == _pngs(drawn.parent) and "report.png" in _pngs(bare.parent)
    for name in _pngs(bare.parent):
        assert imread(bare.parent / name).shape == imread(drawn.parent / name).shape


def test_figures_in_the_background_appear_after_replay_returns(tmp_path):
    """A terminal user does not wait for matplotlib: `--figures background` returns with the
    outputs complete, and a process of its own writes the figures next to them."""
    import subprocess
    import sys
    import time

    data = DATA / "radar_tws_demo.mcap"
    out = tmp_path / "o" / "tracks.mcap"
    proc = subprocess.run([sys.executable, "-m", "trackreplay.face.cli", str(data), "--no-rrd", "-q", "--out", str(out),
                           "--figures", "background"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert out.is_file() and (out.parent / "metrics.csv").is_file() and "drawn in the background" in proc.stdout
    deadline = time.monotonic() + 90
    while not {"report.png", "consistency.png"} <= _pngs(out.parent) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert {"report.png", "consistency.png"} <= _pngs(out.parent)
    assert not list(out.parent.glob("*.tmp"))  # each figure appeared whole (written atomically)
