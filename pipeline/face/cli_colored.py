"""``replay colored-report``: the coloured-noise thesis's figures as PNG files (Kwon 1997).

RMSE of position, velocity and acceleration per scan (Figs. 13–15 and 19–21), the IMMs' model
probabilities (Fig. 22) and the AR(1) estimates against the truth (Figs. 8–9, 23–24), from a data
set (replayed in memory) or a data set plus its replay output.
"""

from __future__ import annotations

from pathlib import Path

import click

from trackreplay.errors import InputError


@click.command("colored-report")
@click.argument("data", type=click.Path(dir_okay=False, path_type=Path))
@click.argument("outputs", required=False, type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--output", "out_dir", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Folder for the PNG files and the thesis-style tables (report.txt).")
def colored_report_cmd(data, outputs, out_dir):
    """Thesis figures for a coloured-noise data set (colored-imm, colored-circle, colored-ar).

    \b
    Example:
      replay simulate colored-imm --runs 50 -o imm.mcap
      replay colored-report imm.mcap -o figs/   # rmse.png, model_probabilities.png, ar_alpha.png, ar_noise_variance.png
      replay simulate colored-ar --runs 250 -o ar.mcap && replay colored-report ar.mcap -o ar-figs/
    """
    import polars as pl

    from trackreplay.evaluators.colored import write_figures
    from trackreplay import vocabulary as vocab
    from trackreplay.contract import atomic_output
    from trackreplay.replay import evaluate_files
    from trackreplay.stages.colored import ColoredStage

    stage = ColoredStage()
    res = evaluate_files(data, outputs)
    per_scan = res.per_scan.filter(pl.col("stage") == stage.name) if "stage" in res.per_scan.columns else res.per_scan
    if per_scan.height == 0:
        raise InputError(f"holds no coloured-noise measurements ({vocab.CHANNELS['colored_measurements']})", data)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = write_figures(per_scan, out_dir, title=data.name)
    text = stage.report(res.summary, per_scan)
    with atomic_output(out_dir / "report.txt", "w") as f:
        f.write(text + "\n")
    click.echo(text)
    for p in paths + [out_dir / "report.txt"]:
        click.echo(f"wrote {p}")


COMMANDS = [colored_report_cmd]
