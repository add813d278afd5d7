"""``replay fit-peaks``: fit the cross-correlation peak model (λV, σ_p, ẑ_a, σ_a, α) to a data set."""

from __future__ import annotations

import json
import math
from pathlib import Path

import click

from trackreplay.errors import InputError

PAPER = {"strong": {"clutter_per_gate": 2.0, "amplitude_mean": 21000.0, "amplitude_std": 2500.0, "sigma_p_deg": 1.3},
         "weak": {"clutter_per_gate": 3.0, "amplitude_mean": 12000.0, "amplitude_std": 3500.0, "sigma_p_deg": 1.8},
         "background": {"clutter_per_gate": 2.0, "clutter_alpha": 4e-4}}


def reference_bearings(dataset, reference: str):
    """Reference bearings ``(R, K, T)``: the truth, or a tracker's estimates (as the paper's PDA tracks)."""
    from trackreplay import design_values, stage_running
    from trackreplay.stages.xcorr import PEAKS, TRUTH, XcorrStage, read_truth

    truth = dataset.channels.get(TRUTH)
    if reference == "auto":
        reference = "truth" if truth is not None and "bearing_rad" in truth.arrays else "jpda_a"
    if reference == "truth":
        peaks = dataset.channel(PEAKS)
        bearings = read_truth(dataset, peaks.n_runs, peaks.n_scans)
        if bearings is None:
            raise InputError(f"no {TRUTH} channel: use --reference jpda_a (tracker estimates)", dataset.path)
        return bearings, reference
    stage = XcorrStage()
    overrides = {} if truth is not None else {"track_start": "two-point"}
    entries = [e for e in stage.entries() if e.name == reference]
    design = design_values.resolve(stage, dataset, overrides, entries)
    out = stage_running.run(stage, dataset, entries, design)["tracks"][reference]
    return out["state"][..., 0], reference


def fit_dataset(path, reference: str = "auto", gate_deg: float | None = None, threshold: float = 0.0):
    """Read a peak data set and fit the model; returns ``(PeakModelFit, roles)``."""
    from trackreplay.contract import read_dataset
    from trackreplay.cores.association.peak_model_fit import fit_peak_model
    from trackreplay.stages.xcorr import field_deg, read_peaks, recorded_float

    ds = read_dataset(path)
    peaks = read_peaks(ds)
    params = ds.scenario.get("params", {})
    gate = math.radians(gate_deg if gate_deg is not None else recorded_float(ds, "gate_deg", 10.0))
    if not gate > 0:
        raise InputError("--gate-deg must be > 0")
    ref, name = reference_bearings(ds, reference)
    field = tuple(math.radians(float(v)) for v in field_deg(ds))
    fit = fit_peak_model(peaks["bearing"], peaks["amplitude"], peaks["run"], peaks["scan"], ref, gate, threshold,
                         field, name)
    from trackreplay.trackers.xcorr_peak_roles import roles_for

    # the recorded roles cycled over the data's targets (a recording without them: track0, …)
    roles = (list(roles_for(params, len(fit.tracks))) if "pair" in params or "roles" in params
             else [f"track{t}" for t in range(len(fit.tracks))])
    if len(set(roles)) < len(roles):  # a role shared by several targets: name them apart
        roles = [f"track{t}:{role}" for t, role in enumerate(roles)]
    return fit, roles


def format_fit(fit, roles) -> str:
    lines = [f"peak model fitted in gates of V = {fit.gate_deg:g}° around the {fit.reference} bearings, "
             f"amplitude threshold {fit.threshold:g} (± one standard error)",
             f"{'':<12} {'λV':>14} {'σ_p (°)':>16} {'ẑ_a':>18} {'σ_a':>16} {'α (clutter)':>20} {'P_D':>14} {'gates':>7}"]
    for role, tf in zip(roles, fit.tracks):
        v, e = tf.values, tf.stderr
        lines.append(f"{role:<12} {v['clutter_per_gate']:>7.3f} ± {e['clutter_per_gate']:<5.3f}"
                     f"{v['sigma_p_deg']:>8.3f} ± {e['sigma_p_deg']:<6.3f}"
                     f"{v['amplitude_mean']:>9.0f} ± {e['amplitude_mean']:<6.0f}"
                     f"{v['amplitude_std']:>8.0f} ± {e['amplitude_std']:<5.0f}"
                     f"{v['clutter_alpha']:>11.3e} ± {e['clutter_alpha']:<8.1e}"
                     f"{v['detection_probability']:>6.3f} ± {e['detection_probability']:<5.3f}{tf.gates:>7d}")
    bg = fit.background
    if bg is not None:
        lines.append(f"{'background':<12} {bg.clutter_per_gate:>7.3f}{'':<41}{'':<25}{bg.clutter_alpha:>11.3e}"
                     f"{'':<25}{bg.gates:>7d}")
        lines.append(f"model checks (background): count variance/mean {bg.count_dispersion:.3f} (Poisson: 1), "
                     f"KS p-value positions uniform {bg.uniform_ks_pvalue:.3g}, amplitudes exponential "
                     f"{bg.exponential_ks_pvalue:.3g}")
    lines += [f"note: {n}" for n in fit.notes]
    lines.append("paper (sea trial): strong λV 2, ẑ_a 21000, σ_a 2500, σ_p 1.3°; weak λV 3, ẑ_a 12000, σ_a 3500, "
                 "σ_p 1.8°; background λV 2, α 4e-4")
    sets = []
    for role, tf in zip(roles, fit.tracks):
        if role in ("strong", "weak"):
            v = tf.values
            sets += [f"{role}_clutter_per_gate={v['clutter_per_gate']:.3g}", f"{role}_amplitude_mean={v['amplitude_mean']:.5g}",
                     f"{role}_amplitude_std={v['amplitude_std']:.4g}", f"{role}_sigma_p_deg={v['sigma_p_deg']:.3g}"]
    if bg is not None:
        sets += [f"background_clutter_per_gate={bg.clutter_per_gate:.3g}", f"clutter_alpha={bg.clutter_alpha:.3g}"]
    if sets:
        lines.append("calibrate the simulator: replay simulate xcorr-crossing " + " ".join(f"--set {s}" for s in sets) + " -o sim.mcap")
    return "\n".join(lines)


def fit_records(fit, roles) -> list[dict]:
    recs = []
    for role, tf in zip(roles, fit.tracks):
        for k, v in tf.values.items():
            recs.append({"track": role, "parameter": k, "value": v, "stderr": tf.stderr[k], "gates": tf.gates})
    if fit.background is not None:
        bg = fit.background
        for k in ("clutter_per_gate", "clutter_alpha", "count_dispersion", "uniform_ks_pvalue", "exponential_ks_pvalue"):
            recs.append({"track": "background", "parameter": k, "value": getattr(bg, k), "stderr": None, "gates": bg.gates})
    return recs


@click.command("fit-peaks")
@click.argument("data", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--reference", type=click.Choice(["auto", "truth", "jpda", "jpda_a"]), default="auto", show_default=True,
              help="Gate centres: the truth bearings, or a tracker's estimates (auto: truth if the file has it).")
@click.option("--gate-deg", type=float, help="Gate width V in degrees (default: the file's gate_deg, else 10).")
@click.option("--threshold", type=float, default=0.0, show_default=True, help="Amplitude threshold before fitting.")
@click.option("--json", "as_json", is_flag=True, help="Print records {track, parameter, value, stderr, gates}.")
def fit_peaks_cmd(data, reference, gate_deg, threshold, as_json):
    """Fit the paper's peak model (λV, σ_p, ẑ_a, σ_a, α, P_D) to a peak data set and print it.

    Peaks within half a gate of each reference bearing are a mixture of at most one true peak
    (Gaussian position and amplitude) and Poisson clutter (uniform position, exponential
    amplitude); the fit is maximum likelihood over that mixture. The last line is a
    `replay simulate` command that makes artificial data with the fitted values.

    \b
    Example:
      replay simulate xcorr-signals --runs 20 --seed 1 -o sig.mcap
      replay fit-peaks sig.mcap
      replay fit-peaks recorded.mcap --reference jpda_a --threshold 0 --json
    """
    fit, roles = fit_dataset(data, reference, gate_deg, threshold)
    if as_json:
        click.echo(json.dumps(fit_records(fit, roles)))
    else:
        click.echo(format_fit(fit, roles))


def read_study(study: Path):
    """A ``replay sweep`` folder's spec and table, checked: ``(spec, swept parameter names, table)``.

    Raises
    ------
    InputError
        Naming the folder: no sweep files, a sweep.json that is not JSON or has no swept
        ``params``, an unreadable sweep.parquet or one without the sweep table's columns.
    """
    import polars as pl

    table_path, spec_path = study / "sweep.parquet", study / "sweep.json"
    if not table_path.exists() or not spec_path.exists():
        raise InputError("not a sweep folder (no sweep.parquet / sweep.json)", study)
    try:
        spec = json.loads(spec_path.read_text())
    except (ValueError, OSError) as exc:  # JSONDecodeError and UnicodeDecodeError are ValueErrors
        raise InputError(f"sweep.json is not readable JSON ({exc})", study) from None
    params = spec.get("params") if isinstance(spec, dict) else None
    if not isinstance(params, dict) or not params:
        raise InputError("sweep.json names no swept parameters (expected \"params\": {name: [values, ...]})", study)
    swept = [str(k) for k in params]
    try:
        table = pl.read_parquet(table_path)
    except (pl.exceptions.PolarsError, OSError) as exc:
        raise InputError(f"sweep.parquet is unreadable ({str(exc).splitlines()[0]})", study) from None
    missing = [c for c in (*swept, "tracker", "metric", "value") if c not in table.columns]
    if missing:
        raise InputError(f"sweep.parquet lacks column(s) {', '.join(missing)}", study)
    return spec, swept, table


def association_table(table, swept: list[str], path=None):
    """Fig. 8 rows from a sweep table: one row per grid point and tracker, success/swap/loss."""

    wide = table.pivot(on="metric", index=[*swept, "tracker"], values="value", aggregate_function="first")
    if "success_rate" not in wide.columns:
        raise InputError("the sweep has no success_rate metric (needs /xcorr/truth): not an xcorr study", path)
    missing = [c for c in ("success_rate_stderr", "swap_rate", "loss_rate", "runs") if c not in wide.columns]
    if missing:
        raise InputError(f"the sweep lacks metric(s) {', '.join(missing)}: not an xcorr study", path)
    return wide.select(*swept, "tracker", "success_rate", "success_rate_stderr", "swap_rate", "loss_rate", "runs").sort(
        [*swept[1:], swept[0], "tracker"])


def plot_association(panels, path: Path) -> Path:
    """Success rate vs the swept parameter, one panel per study, one line per tracker, with its
    95 % Wilson interval (which, unlike ± 1.96 SE, stays inside 0–100 %)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    import numpy as np

    from trackreplay.evaluators.confidence import wilson_interval
    from trackreplay.evaluators.report_plots import legend_outside, save_figure, series_style

    fig, axes = plt.subplots(1, len(panels), figsize=(5.5 * len(panels), 3.8), squeeze=False)
    for ax, (title, rows, swept) in zip(axes[0], panels):
        x = swept[0]
        keys = ["tracker", *swept[1:]]
        for i, (key, part) in enumerate(rows.group_by(keys, maintain_order=True)):
            label = " ".join(f"{k}={v}" if k != "tracker" else str(v) for k, v in zip(keys, key))
            part = part.sort(x)
            rate, runs = part["success_rate"].to_numpy(), part["runs"].to_numpy()
            low, high = wilson_interval(rate * runs, runs)
            # (at a rate of 0 or 1 one end of the interval is the rate itself, up to rounding)
            spread = np.clip(np.stack([rate - low, high - rate]), 0.0, None)
            ax.errorbar(part[x].to_numpy(), 100 * rate, yerr=100 * spread, capsize=3,
                        label=label, **series_style(i))
        ax.set_xlabel(x)
        ax.set_ylabel("success (%)")
        ax.set_ylim(0, 102)
        ax.grid(alpha=0.3)
        ax.set_title(title, fontsize="medium")
    legend_outside(axes[0, -1])
    # wrapped: one study's figure is narrower than the title
    fig.suptitle("track-association success, JPDA vs JPDA_A\n(cf. Park, Ryu & Lee 1994, Fig. 8)", fontsize="medium")
    return save_figure(fig, path)


@click.command("association-table", short_help="Print and plot the Fig. 8 table of xcorr sweeps.")
@click.argument("studies", nargs=-1, required=True, type=click.Path(file_okay=False, path_type=Path))
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path),
              help="The figure (default: fig8.png in the first study folder).")
def association_table_cmd(studies, output):
    """Print the Fig. 8 table (success / swap / loss per grid point) of xcorr sweeps and plot it.

    One panel per study folder written by `replay sweep` (e.g. one crossing, one maneuver).

    \b
    Example:
      replay sweep xcorr-crossing --param crossing_angle_deg=2,5,10,20,30 --runs 100 -o crossing/
      replay sweep xcorr-maneuver --param min_distance_deg=0.5,1,2,4,8 --runs 100 -o maneuver/
      replay association-table crossing/ maneuver/
    """
    from trackreplay.evaluators.confidence import wilson_interval

    panels = []
    for study in studies:
        spec, swept, table = read_study(study)
        rows = association_table(table, swept, study)
        click.echo(f"{spec.get('scenario', study)} ({study}); success = every track ends on its own target and was "
                   "never on another; 95 % Wilson interval")
        click.echo(f"{'  '.join(f'{s:>18}' for s in swept)} {'tracker':<8} {'success %':>9} {'95 % interval':>13} "
                   f"{'swap %':>7} {'loss %':>7} {'runs':>5}")
        for r in rows.iter_rows(named=True):
            low, high = wilson_interval(r["success_rate"] * r["runs"], r["runs"])
            values = "  ".join(f"{_plain(r[s]):>18}" for s in swept)
            click.echo(f"{values} {r['tracker']:<8} {100 * r['success_rate']:>9.1f} "
                       f"{f'{100 * max(low, 0):.1f}–{100 * min(high, 1):.1f}':>13} "
                       f"{100 * r['swap_rate']:>7.1f} {100 * r['loss_rate']:>7.1f} {int(r['runs']):>5d}")
        click.echo("")
        panels.append((str(spec.get("scenario", study)), rows, swept))
    path = plot_association(panels, output or studies[0] / "fig8.png")
    click.echo(f"figure: {path}")


def _plain(value) -> str:
    """A swept value as typed: 2 rather than 2.0."""
    return f"{value:g}" if isinstance(value, float) else str(value)


COMMANDS = [fit_peaks_cmd, association_table_cmd]
