"""PNG figures for reports (matplotlib, headless)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import polars as pl  # noqa: E402

from pipeline.contract import atomic_output  # noqa: E402


def plot_metrics_vs(table: pl.DataFrame, x: str, metrics: list[str], path: str | Path,
                    group: str = "tracker", title: str = "", hlines: dict | None = None) -> Path:
    """One panel per metric, one line per ``group`` value, written atomically to ``path``."""
    fig, axes = plt.subplots(len(metrics), 1, figsize=(8, 2.6 * len(metrics)), sharex=True, squeeze=False)
    for ax, metric in zip(axes[:, 0], metrics):
        for (name,), part in table.sort(x).group_by([group], maintain_order=True):
            ax.plot(part[x].to_numpy(), part[metric].to_numpy(), marker="." if part.height < 30 else None,
                    label=str(name))
        for y in (hlines or {}).get(metric, []):
            ax.axhline(y, color="grey", lw=0.8, ls="--")
        ax.set_ylabel(metric)
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize="small", ncol=4)
    axes[-1, 0].set_xlabel(x)
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


STYLES = [("-", "o"), ("--", "s"), ("-.", "^"), (":", "D"), ((0, (5, 1, 1, 1)), "v"), ((0, (3, 1)), "x")]


def plot_consistency(per_scan: pl.DataFrame, path: str | Path, title: str = "") -> Path | None:
    """Filter consistency and set distance per scan: ANEES and ANIS with their two-sided 95 % χ²
    bounds for the runs present (shaded), and OSPA; every tracker with its own line style and
    marker, the legend outside the data (``docs/evaluation.md``)."""
    panels = [(m, lo, hi, label) for m, lo, hi, label in
              (("anees", "anees_low", "anees_high", "ANEES"), ("anis", "anis_low", "anis_high", "ANIS"),
               (next((c for c in per_scan.columns if c.startswith("ospa_")), None), None, None, "OSPA"))
              if m is not None and m in per_scan.columns and per_scan[m].drop_nulls().len() > 0]
    if not panels:
        return None
    fig, axes = plt.subplots(len(panels), 1, figsize=(9, 2.4 * len(panels) + 0.6), sharex=True, squeeze=False)
    trackers = per_scan.filter(pl.col(panels[0][0]).is_not_null())["tracker"].unique(maintain_order=True).to_list()
    for ax, (metric, lo, hi, label) in zip(axes[:, 0], panels):
        for i, name in enumerate(trackers):
            part = per_scan.filter(pl.col("tracker") == name).sort("scan")
            ls, marker = STYLES[i % len(STYLES)]
            ax.plot(part["scan"].to_numpy(), part[metric].to_numpy(), ls=ls, marker=marker, markevery=max(1, part.height // 12),
                    ms=4, lw=1.1, label=name)
            if lo and i == 0:
                ax.fill_between(part["scan"].to_numpy(), part[lo].to_numpy(), part[hi].to_numpy(), color="grey",
                                alpha=0.2, label="95 % χ² bounds")
        ax.set_ylabel(metric if label == "OSPA" else label)
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize="small", loc="upper left", bbox_to_anchor=(1.01, 1.0))
    axes[-1, 0].set_xlabel("scan")
    if title:
        fig.suptitle(title)
    return save_figure(fig, path)
