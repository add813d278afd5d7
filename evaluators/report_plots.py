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
