"""PNG figures for reports (matplotlib, headless)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import polars as pl  # noqa: E402

from trackreplay.contract import atomic_output  # noqa: E402

# line style and marker per series, cycled with the colours (see series_style)
STYLES = [("-", "o"), ("--", "s"), ("-.", "^"), (":", "D"), ((0, (5, 1, 1, 1)), "v"), ((0, (3, 1)), "x")]


def series_style(i: int) -> dict:
    """Colour, line style and marker of the i-th series: each alone tells the series apart, so
    curves lying on top of each other (two trackers that agree) stay distinguishable."""
    ls, marker = STYLES[i % len(STYLES)]
    return {"color": f"C{i % 10}", "ls": ls, "marker": marker}


def staggered_markers(n_points: int, i: int, per_line: int = 12):
    """``markevery`` for series i: about ``per_line`` markers, shifted from series to series so
    that the markers of curves lying on top of each other do not hide one another."""
    step = max(1, n_points // per_line)
    return (int(i * step / 4) % step, step)


def legend_outside(ax, **kwargs) -> None:
    """The legend to the right of the axes, never over the data."""
    ax.legend(fontsize="small", loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, **kwargs)


def plot_metrics_vs(table: pl.DataFrame, x: str, metrics: list[str], path: str | Path,
                    group: str = "tracker", title: str = "", hlines: dict | None = None,
                    log_x: bool = False, log_y: bool = False) -> Path:
    """One panel per metric, one series per ``group`` value (its own colour, line style and
    marker), the legend outside the data; written atomically to ``path``."""
    fig, axes = plt.subplots(len(metrics), 1, figsize=(9, 2.6 * len(metrics) + 0.5), sharex=True, squeeze=False)
    for ax, metric in zip(axes[:, 0], metrics):
        for i, ((name,), part) in enumerate(table.sort(x).group_by([group], maintain_order=True)):
            style = series_style(i)
            ax.plot(part[x].to_numpy(), part[metric].to_numpy(), markevery=staggered_markers(part.height, i), ms=4,
                    lw=1.1,
                    label=str(name), **style)
        for y in (hlines or {}).get(metric, []):
            ax.axhline(y, color="grey", lw=0.8, ls="--")
        ax.set_ylabel(metric)
        ax.grid(alpha=0.3)
        if log_x:
            ax.set_xscale("log")
        if log_y:
            ax.set_yscale("log")
    legend_outside(axes[0, 0])
    axes[-1, 0].set_xlabel(x)
    if title:
        fig.suptitle(title)
    return save_figure(fig, path)


def plot_facets(table: pl.DataFrame, x: str, metric: str, facets: list[str], path: str | Path,
                group: str = "tracker", title: str = "") -> Path:
    """``metric`` against ``x``, one panel per combination of the ``facets`` columns' values, one
    series per ``group`` value: readable for any number of swept parameters."""
    keys = table.select(facets).unique(maintain_order=True).sort(facets).rows()
    ncols = min(3, len(keys))
    nrows = -(-len(keys) // ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(4.2 * ncols + 1.6, 3.0 * nrows + 0.6), sharex=True, sharey=True,
                             squeeze=False)
    groups = table[group].unique(maintain_order=True).to_list()
    for ax, key in zip(axes.ravel(), keys):
        part = table.filter(pl.all_horizontal([pl.col(c) == v for c, v in zip(facets, key)])).sort(x)
        for i, name in enumerate(groups):
            line = part.filter(pl.col(group) == name)
            if line.height:
                ax.plot(line[x].to_numpy(), line[metric].to_numpy(), ms=4, lw=1.1, label=str(name), **series_style(i))
        ax.set_title(", ".join(f"{c} = {v}" for c, v in zip(facets, key)), fontsize="small")
        ax.grid(alpha=0.3)
    for ax in axes.ravel()[len(keys):]:
        ax.set_visible(False)
    for ax in axes[-1]:
        ax.set_xlabel(x)
    for ax in axes[:, 0]:
        ax.set_ylabel(metric)
    legend_outside(axes[0, -1] if len(keys) >= ncols else axes[0, 0])
    if title:
        fig.suptitle(title)
    return save_figure(fig, path)


def plot_bearing_time(times_s, tracks_deg: dict, path: str | Path, truth_deg=None, peaks=None,
                      field_deg=None, title: str = "") -> Path:
    """A bearing–time record of one run: time down the page as on a sonar display, the
    measurements as grey dots, the truth dashed, every tracker's tracks in its own style.

    Parameters
    ----------
    times_s : ndarray (K,)
    tracks_deg : dict
        ``tracker -> (K, S)`` bearings in degrees, NaN where a slot holds no track.
    truth_deg : ndarray (K, T), optional
    peaks : tuple of ndarray ``(time_s, bearing_deg)``, optional
        Every measured bearing of the run.
    field_deg : (low, high), optional
        The sensor's field of view (its edges drawn).
    """
    fig, ax = plt.subplots(figsize=(9, 6))
    t = np.asarray(times_s, float)
    if peaks is not None and len(peaks[0]):
        ax.plot(peaks[1], peaks[0], ".", color="0.65", ms=2.5, label="measured bearings", zorder=1)
    if truth_deg is not None:
        truth = np.asarray(truth_deg, float).reshape(len(t), -1)
        for j in range(truth.shape[1]):
            ax.plot(truth[:, j], t, color="k", ls="--", lw=1.0, label="truth" if j == 0 else None, zorder=2)
    for i, (name, bearings) in enumerate(tracks_deg.items()):
        b = np.asarray(bearings, float).reshape(len(t), -1)
        style = series_style(i)
        for j in range(b.shape[1]):
            if np.isfinite(b[:, j]).any():
                ax.plot(b[:, j], t, lw=1.3, ms=3.5, markevery=staggered_markers(len(t), i, 15), label=name if j == 0 else None,
                        zorder=3, **style)
    if field_deg is not None:
        for edge in field_deg:
            ax.axvline(edge, color="grey", lw=0.8, ls=":")
    ax.invert_yaxis()
    ax.set_xlabel("bearing (deg)")
    ax.set_ylabel("time (s)")
    ax.grid(alpha=0.3)
    legend_outside(ax)
    if title:
        ax.set_title(title)
    return save_figure(fig, path)


def plot_tracks_xy(tracks_m: dict, path: str | Path, measured_m=None, truth_m=None, title: str = "") -> Path:
    """One run's tracks in the plane (km): the measured positions as grey dots, the truth dashed,
    every tracker in its own style, its start marked.

    Parameters
    ----------
    tracks_m : dict
        ``tracker -> (K, 2)`` positions, NaN where there is no track, or ``(K, S, 2)`` for a
        tracker with track slots (each slot a line, broken where it holds no track).
    measured_m : ndarray (N, 2), optional
    truth_m : ndarray (K, 2) or (K, T, 2), optional
    """
    fig, ax = plt.subplots(figsize=(8, 6.5))
    if measured_m is not None and len(measured_m):
        m = np.asarray(measured_m, float) / 1e3
        many = len(m) > 2000  # clutter: smaller, lighter dots keep the tracks readable
        ax.plot(m[:, 0], m[:, 1], ".", color="0.75" if many else "0.6", ms=1.5 if many else 3,
                label="measured positions", zorder=1)
    if truth_m is not None:
        t = np.asarray(truth_m, float) / 1e3
        t = t[:, None] if t.ndim == 2 else t
        for j in range(t.shape[1]):
            ax.plot(t[:, j, 0], t[:, j, 1], color="k", ls="--", lw=1.0 if t.shape[1] == 1 else 0.7,
                    label="truth" if j == 0 else None, zorder=2)
    for i, (name, xy) in enumerate(tracks_m.items()):
        xy = np.asarray(xy, float) / 1e3
        if xy.ndim == 3:
            style = {k: v for k, v in series_style(i).items() if k != "marker"}
            for j in range(xy.shape[1]):
                ax.plot(xy[:, j, 0], xy[:, j, 1], lw=1.0, label=name if j == 0 else None, zorder=3, **style)
            continue
        ax.plot(xy[:, 0], xy[:, 1], lw=1.2, ms=3.5, markevery=staggered_markers(len(xy), i), label=name, zorder=3,
                **series_style(i))
    ax.set_xlabel("x (km)")
    ax.set_ylabel("y (km)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    legend_outside(ax)
    if title:
        ax.set_title(title)
    return save_figure(fig, path)


def plot_positions_time(times_s, tracks_m: dict, path: str | Path, measured_m=None, truth_m=None,
                        title: str = "", model_probabilities: dict | None = None, model_names=()) -> Path:
    """One run's position per axis against time: one panel per axis, the measurements as grey
    dots, the truth dashed, every tracker in its own style; below them, for every IMM, a panel of
    its posterior model probabilities (what a recording without truth shows of the IMMs).

    Parameters
    ----------
    times_s : ndarray (K,)
    tracks_m : dict
        ``tracker -> (K, axes)`` positions.
    measured_m, truth_m : ndarray (K, axes), optional
    model_probabilities : dict, optional
        ``tracker -> (K, M)`` posterior model probabilities.
    model_names : sequence of str
        The M models' names.
    """
    t = np.asarray(times_s, float)
    axes_n = next(iter(tracks_m.values())).shape[-1] if tracks_m else 1
    probs = dict(model_probabilities or {})
    rows = axes_n + len(probs)
    fig, axes = plt.subplots(rows, 1, figsize=(9, 2.8 * axes_n + 1.6 * len(probs) + 0.6), sharex=True, squeeze=False)
    for a, ax in enumerate(axes[:axes_n, 0]):
        if measured_m is not None:
            ax.plot(t, np.asarray(measured_m, float)[:, a], ".", color="0.6", ms=2.5, label="measurements", zorder=1)
        if truth_m is not None:
            ax.plot(t, np.asarray(truth_m, float)[:, a], color="k", ls="--", lw=1.0, label="truth", zorder=2)
        for i, (name, p) in enumerate(tracks_m.items()):
            ax.plot(t, np.asarray(p, float)[:, a], lw=1.1, ms=3.5, markevery=staggered_markers(len(t), i), label=name,
                    zorder=3, **series_style(i))
        ax.set_ylabel(f"position, axis {a} (m)" if axes_n > 1 else "position (m)")
        ax.grid(alpha=0.3)
    legend_outside(axes[0, 0])
    for ax, (name, mu) in zip(axes[axes_n:, 0], probs.items()):
        mu = np.asarray(mu, float)
        for j in range(mu.shape[-1]):
            label = model_names[j] if j < len(model_names) else f"model {j}"
            ax.plot(t, mu[:, j], lw=1.0, ms=3.5, markevery=staggered_markers(len(t), j), label=label,
                    **series_style(j))
        ax.set_ylim(-0.02, 1.02)
        ax.set_ylabel(f"{name}\nP(model)")
        ax.grid(alpha=0.3)
        legend_outside(ax)
    axes[-1, 0].set_xlabel("time (s)")
    if title:
        fig.suptitle(title)
    return save_figure(fig, path)


def ellipse_points(centre, covariance, prob: float = 0.95, n: int = 120):
    """Points of the ``prob`` ellipse of a 2-D Gaussian (boundary ``dᵀ C⁻¹ d = χ²₂(prob)``)."""
    radius = np.sqrt(-2.0 * np.log1p(-prob))           # the χ²₂ quantile has this closed form
    L = np.linalg.cholesky(np.asarray(covariance, float))
    angle = np.linspace(0.0, 2 * np.pi, n)
    circle = radius * np.stack([np.cos(angle), np.sin(angle)])
    return np.asarray(centre, float)[:, None] + L @ circle


def plot_emitter_geometry(sensors_m, sensor_velocity_mps, path: str | Path, truth_m=None, estimates: dict | None = None,
                          covariances: dict | None = None, bound_covariance=None, title: str = "") -> Path:
    """Sensors (with their velocity), the emitter's true position, every tracker's estimates over
    the Monte Carlo runs, the 95 % ellipse of the covariance each tracker reports (its median over
    the runs, around the median estimate), and the CRLB's 95 % ellipse around the truth.

    Two panels: the geometry, framed on the sensors and the emitter, and a zoom on the emitter
    framed on the bound's ellipse; estimates outside a frame are counted in the legend.
    """
    sensors = np.asarray(sensors_m, float)
    velocity = np.asarray(sensor_velocity_mps, float)
    truth = None if truth_m is None else np.asarray(truth_m, float)[:2]
    fig, (overview, zoom) = plt.subplots(1, 2, figsize=(12.5, 5.4))
    overview.plot(sensors[:, 0] / 1e3, sensors[:, 1] / 1e3, "^", color="k", ms=8, label="sensors")
    for ax in (overview, zoom):
        if truth is not None:
            ax.plot(truth[0] / 1e3, truth[1] / 1e3, "*", color="k", ms=13, label="emitter (truth)", zorder=5)
    anchors = sensors if truth is None else np.vstack([sensors, truth])
    lo, hi = anchors.min(axis=0), anchors.max(axis=0)
    pad = 0.2 * max(np.max(hi - lo), 1.0)
    frames = {overview: (lo - pad, hi + pad)}
    span = np.max(hi - lo) if len(anchors) > 1 else 1.0
    speed = np.abs(velocity).max()
    if speed > 0:
        scale = 0.12 * span / speed
        overview.quiver(sensors[:, 0] / 1e3, sensors[:, 1] / 1e3, velocity[:, 0] * scale / 1e3,
                        velocity[:, 1] * scale / 1e3, angles="xy", scale_units="xy", scale=1, color="0.4", width=0.004)
    # the zoom frames the truth and every ellipse (the bound's and the reported ones), not the
    # runs that went astray: those are counted in the legend instead
    ellipses = []
    if bound_covariance is not None and truth is not None:
        ellipses.append(("CRLB 95 % around the truth", {"color": "k", "ls": "--"}, ellipse_points(truth, bound_covariance)))
    clouds = {}
    for i, (name, xy) in enumerate((estimates or {}).items()):
        xy = np.asarray(xy, float)
        xy = xy[np.isfinite(xy).all(axis=1)]
        if not len(xy):
            continue
        clouds[name] = (series_style(i), xy)
        cov = None if covariances is None else covariances.get(name)
        if cov is not None and np.all(np.isfinite(cov)) and np.all(np.linalg.eigvalsh(cov) > 0):
            style = series_style(i)
            ellipses.append((f"{name}: reported 95 %", {"color": style["color"], "ls": style["ls"]},
                             ellipse_points(np.median(xy, axis=0), cov)))
    framed = [e.T for _, _, e in ellipses] + ([truth[None]] if truth is not None else [])
    if framed:
        pts = np.vstack(framed)
        centre, half = (pts.min(axis=0) + pts.max(axis=0)) / 2, 0.6 * max(np.ptp(pts, axis=0).max(), 1.0)
        frames[zoom] = (centre - half, centre + half)
    for label, style, e in ellipses:
        zoom.plot(e[0] / 1e3, e[1] / 1e3, lw=1.3, label=label, **style)
    for name, (style, xy) in clouds.items():
        for ax in (overview, zoom):
            low, high = frames.get(ax, (xy.min(axis=0), xy.max(axis=0)))
            inside = np.all((xy >= low) & (xy <= high), axis=1)
            outside = f", {int((~inside).sum())} outside the zoom" if (~inside).any() else ""
            ax.plot(xy[inside, 0] / 1e3, xy[inside, 1] / 1e3, ls="none", marker=style["marker"], color=style["color"],
                    ms=3, alpha=0.5, label=f"{name}: {len(xy)} runs{outside}" if ax is zoom else "_nolegend_")
    for ax, (low, high) in frames.items():
        ax.set_xlim(low[0] / 1e3, high[0] / 1e3)
        ax.set_ylim(low[1] / 1e3, high[1] / 1e3)
    for ax, name in ((overview, "geometry"), (zoom, "around the emitter")):
        ax.set_xlabel("x (km)")
        ax.set_ylabel("y (km)")
        ax.set_aspect("equal", adjustable="box")
        ax.grid(alpha=0.3)
        ax.set_title(name, fontsize="medium")
    handles, labels = [], []
    for ax in (overview, zoom):
        for h, label in zip(*ax.get_legend_handles_labels()):
            if label not in labels:
                handles.append(h)
                labels.append(label)
    zoom.legend(handles, labels, fontsize="small", loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    if title:
        fig.suptitle(title)
    return save_figure(fig, path)


def save_figure(fig, path: str | Path, dpi: int = 110) -> Path:
    """Lay out, write atomically as PNG and close a matplotlib figure (the one way figures leave)."""
    fig.tight_layout()
    path = Path(path)
    with atomic_output(path) as f:
        fig.savefig(f, format="png", dpi=dpi)
    plt.close(fig)
    return path


def plot_consistency(per_scan: pl.DataFrame, path: str | Path, title: str = "", x: str = "scan",
                     log_x: bool = False) -> Path | None:
    """Filter consistency and set distance per scan: ANEES and ANIS with their two-sided 95 % χ²
    bounds for the runs present (shaded), and OSPA; every tracker with its own line style and
    marker, the legend outside the data (``docs/evaluation.md``). ``x`` is the per-scan column
    the scans stand for (e.g. the noise level of a noise study). None when there is nothing to
    draw or fewer than two scans (a single value is a table entry, not a curve). A consistency
    panel whose values spread over more than two decades is drawn on a log scale, so that the
    bounds stay visible next to a badly inconsistent tracker."""
    panels = [(m, lo, hi, label) for m, lo, hi, label in
              (("anees", "anees_low", "anees_high", "ANEES"), ("anis", "anis_low", "anis_high", "ANIS"),
               (next((c for c in per_scan.columns if c.startswith("ospa_")), None), None, None, "OSPA"))
              if m is not None and m in per_scan.columns and per_scan[m].drop_nulls().len() > 0]
    if not panels or x not in per_scan.columns or per_scan[x].n_unique() < 2:
        return None
    fig, axes = plt.subplots(len(panels), 1, figsize=(9, 2.4 * len(panels) + 0.6), sharex=True, squeeze=False)
    trackers = per_scan.filter(pl.col(panels[0][0]).is_not_null())["tracker"].unique(maintain_order=True).to_list()
    for ax, (metric, lo, hi, label) in zip(axes[:, 0], panels):
        for i, name in enumerate(trackers):
            part = per_scan.filter(pl.col("tracker") == name).sort(x)
            ax.plot(part[x].to_numpy(), part[metric].to_numpy(), markevery=staggered_markers(part.height, i),
                    ms=4, lw=1.1, label=name, **series_style(i))
            if lo and i == 0:
                ax.fill_between(part[x].to_numpy(), part[lo].to_numpy(), part[hi].to_numpy(), color="grey",
                                alpha=0.2, label="95 % χ² bounds")
        values = per_scan[metric].drop_nulls().drop_nans().to_numpy()
        values = values[values > 0]
        if lo and values.size and values.max() > 100 * values.min():
            ax.set_yscale("log")
        ax.set_ylabel(metric if label == "OSPA" else label)
        ax.grid(alpha=0.3)
    if log_x:
        axes[-1, 0].set_xscale("log")
    legend_outside(axes[0, 0])
    axes[-1, 0].set_xlabel(x)
    if title:
        fig.suptitle(title)
    return save_figure(fig, path)
