"""Pictures of CEP planes: a PNG with the paper's contour levels and Rerun images.

Kim et al. (2013), Figs. 5–6 (CEP from the CRLB, eqs. 18–22); see ``docs/papers/tdoa-fdoa.md``.

Rendering only; the numbers come from :func:`trackreplay.cores.localisation.cep_plane.cep_plane`. Grid points where
the bound does not exist are left blank (PNG) or 0 (Rerun depth image, shown as no data).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from trackreplay.cores.localisation.cep_plane import POSITION_CONTOURS_M, VELOCITY_CONTOURS_MPS, CepPlane

PANELS = (("position_m", "position CEP (m)", POSITION_CONTOURS_M),
          ("velocity_mps", "velocity CEP (m/s)", VELOCITY_CONTOURS_MPS))


def _panels(plane: CepPlane):
    return [(key, title, levels) for key, title, levels in PANELS if np.isfinite(getattr(plane, key)).any()]


def write_cep_png(plane: CepPlane, path: str | Path, sensors=None, emitter=None, title: str = "") -> Path:
    """Position and velocity CEP planes side by side (log colour scale, the paper's contours)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm

    from trackreplay.evaluators.report_plots import save_figure

    panels = _panels(plane)
    fig, axes = plt.subplots(1, len(panels), figsize=(6.2 * len(panels), 5.4), squeeze=False)
    xk, yk = plane.x_m / 1e3, plane.y_m / 1e3
    for ax, (key, label, levels) in zip(axes[0], panels):
        z = np.ma.masked_invalid(getattr(plane, key))
        # the colour scale stops at the 95th percentile: near-singular lines would flatten it
        lo, hi = float(z.min()), float(np.quantile(z.compressed(), 0.95))
        mesh = ax.pcolormesh(xk, yk, z, shading="nearest", cmap="viridis",
                             norm=LogNorm(vmin=max(lo, 1e-12), vmax=max(hi, lo * 1.001 + 1e-12)))
        fig.colorbar(mesh, ax=ax, label=label, extend="max")
        cs = ax.contour(xk, yk, z, levels=list(levels), colors=["white", "orange", "red"], linewidths=1.2)
        ax.clabel(cs, fmt=lambda v: f"{v:g}", fontsize=8)
        if sensors is not None:
            s = np.asarray(sensors) / 1e3
            ax.plot(s[:, 0], s[:, 1], "^", color="black", mec="white", ms=7, label="sensors")
        if emitter is not None:
            ax.plot(emitter[0] / 1e3, emitter[1] / 1e3, "*", color="magenta", ms=10, label="emitter")
        ax.set_xlabel("x (km)")
        ax.set_ylabel("y (km)")
        ax.set_aspect("equal")
        ax.set_title(f"{label}, {plane.method} CEP, P = {plane.probability:g}", fontsize=10)
    if title:
        fig.suptitle(title)
    return save_figure(fig, path, dpi=100)


def _to_pixels(plane: CepPlane, xy):
    """World (x, y) in metres → image pixel coordinates (north up)."""
    step_x = plane.x_m[1] - plane.x_m[0] if len(plane.x_m) > 1 else 1.0
    step_y = plane.y_m[1] - plane.y_m[0] if len(plane.y_m) > 1 else 1.0
    xy = np.asarray(xy, float).reshape(-1, 2)
    col = (xy[:, 0] - plane.x_m[0]) / step_x + 0.5
    row = (plane.y_m[-1] - xy[:, 1]) / step_y + 0.5
    return np.stack([col, row], axis=-1)


def log_cep_plane(rec, plane: CepPlane, sensors=None, emitter=None, root: str = "/cep") -> None:
    """CEP planes as Rerun depth images (hover shows the CEP) with the paper's contour lines."""
    import contourpy
    import rerun as rr

    for key, _, levels in _panels(plane):
        z = getattr(plane, key)
        image = np.where(np.isfinite(z), z, 0.0)[::-1].astype(np.float32)  # row 0 = north
        entity = f"{root}/{key.split('_')[0]}"
        finite = z[np.isfinite(z)]
        rec.log(f"{entity}/image", rr.DepthImage(image, meter=1.0, colormap="viridis",
                                                 depth_range=[float(finite.min()), float(np.quantile(finite, 0.95))]),
                static=True)
        gen = contourpy.contour_generator(plane.x_m, plane.y_m, np.ma.masked_invalid(z))
        palette = [(255, 255, 255), (255, 165, 0), (255, 0, 0)]
        for level, rgb in zip(levels, palette):
            strips = [_to_pixels(plane, line) for line in gen.lines(level) if len(line) > 1]
            if strips:
                rec.log(f"{entity}/contour_{level:g}", rr.LineStrips2D(strips, colors=[rgb], radii=[-1.0]), static=True)
        if sensors is not None:
            rec.log(f"{entity}/sensors", rr.Points2D(_to_pixels(plane, sensors), colors=[(0, 0, 0)], radii=[-4.0]),
                    static=True)
        if emitter is not None:
            rec.log(f"{entity}/emitter", rr.Points2D(_to_pixels(plane, emitter), colors=[(255, 0, 255)], radii=[-5.0]),
                    static=True)
