"""What a user sees: progress only on a terminal, where outputs go (and that nothing is silently
replaced), parameters and examples that explain themselves, one table per result that fits 100
columns, and an export that Foxglove / PlotJuggler read (decoded here with mcap and json only)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from trackreplay.face import cli_eval, cli_text, progress
from trackreplay.face.cli import main

SMALL_RADAR = ["--set", "n_scans=16"]


def invoke(runner, *args):
    return runner.invoke(main, [str(a) for a in args])


@pytest.fixture(scope="module")
def radar(tmp_path_factory):
    """A small radar data set and its replay output (written through the Python API)."""
    from trackreplay.replay import replay
    from trackreplay.recorders.scenarios import load_scenario
    from trackreplay.recorders.simulated import record

    folder = tmp_path_factory.mktemp("ux")
    data = folder / "radar.mcap"
    record(data, load_scenario("radar-tws").with_overrides({"n_scans": "16"}), runs=12, seed=3)
    tracks = folder / "out" / "tracks.mcap"
    replay(data, out_path=tracks)
    return data, tracks


@pytest.fixture
def terminal(monkeypatch):
    """Pretend stderr is a terminal (bars are drawn)."""
    monkeypatch.setattr(progress, "_is_terminal", lambda stream: True)


# --------------------------------------------------------------------------- progress


def test_no_bar_and_no_label_lines_when_stderr_is_not_a_terminal(runner, radar):
    data, _ = radar
    res = invoke(runner, "simulate", "radar-tws", "--runs", 2, "-o", "s.mcap", *SMALL_RADAR)
    assert res.exit_code == 0 and res.stderr == "", res.stderr
    res = invoke(runner, data, "--no-rrd")
    assert res.exit_code == 0 and res.stderr == "", res.stderr
    assert "\r" not in res.stdout and "replaying" not in res.stdout
    res = invoke(runner, "eval", data)
    assert res.exit_code == 0 and res.stderr == ""


def test_bars_on_a_terminal_go_to_stderr_and_quiet_turns_them_off(runner, radar, terminal):
    data, _ = radar
    res = invoke(runner, data, "--no-rrd")
    assert res.exit_code == 0, res.output
    assert "replaying radar.mcap: filter" in res.stderr and "\r" in res.stderr
    assert "\r" not in res.stdout and "rmse_position_m" in res.stdout
    res = invoke(runner, "simulate", "radar-tws", "--runs", 2, "-o", "s.mcap", *SMALL_RADAR)
    assert "writing s.mcap" in res.stderr
    res = invoke(runner, "eval", data)
    assert "evaluating radar.mcap" in res.stderr
    for args in (["--quiet", data, "--no-rrd"], ["-q", "run", data, "--no-rrd"], ["run", data, "--no-rrd", "--quiet"],
                 ["eval", data, "-q"], ["simulate", "radar-tws", "--runs", 2, "-o", "q.mcap", "--quiet", *SMALL_RADAR]):
        res = invoke(runner, *args)
        assert res.exit_code == 0 and res.stderr == "", (args, res.stderr)


def test_verbose_prints_the_time_of_each_phase(runner, radar):
    data, _ = radar
    res = invoke(runner, "--verbose", data, "--no-rrd")
    assert res.exit_code == 0, res.output
    for phase in ("read", "filter", "evaluate", "write"):
        assert f"timing: {phase} " in res.stderr, phase
    assert "filter" in res.stdout.splitlines()[-1]  # the time line breaks the total down
    res = invoke(runner, "simulate", "radar-tws", "--runs", 2, "-o", "s.mcap", "-v", *SMALL_RADAR)
    assert "timing: simulate" in res.stderr and "timing: write" in res.stderr


def test_check_shows_progress_per_data_set(runner, tmp_path, radar, terminal):
    data, _ = radar
    folder = tmp_path / "d"
    (folder / "baselines").mkdir(parents=True)
    shutil.copy(data, folder / "a.mcap")
    res = invoke(runner, "check", folder, "--update")
    assert res.exit_code == 0, res.output
    assert "check a" in res.stderr and "1/1" in res.stderr
    assert f"wrote {folder / 'baselines' / 'a.json'}" in res.stdout


def test_the_bar_helper_works_outside_a_command(capsys):
    with progress.bar(3, "points", show_pos=True) as bar:  # what `replay sweep` can use
        bar.update(1)
        bar.echo("a result line")
        bar.update(2)
    captured = capsys.readouterr()
    assert captured.out == "a result line\n" and captured.err == ""  # not a terminal: no bar
    b = progress.Bar(4, "x", show_pos=True, enabled=True)
    b.update(2)
    assert "[" in b._line() and "2/4" in b._line()


# --------------------------------------------------------------------------- where things go


def test_check_update_writes_into_the_folder_checked(runner, tmp_path, radar, monkeypatch):
    data, _ = radar
    checkout = tmp_path / "checkout"
    (checkout / "data" / "baselines").mkdir(parents=True)
    (checkout / "pyproject.toml").write_text("[project]\nname = 'x'\n")
    shutil.copy(data, checkout / "data" / "a.mcap")
    (checkout / "sub").mkdir()
    monkeypatch.chdir(checkout / "sub")
    res = invoke(runner, "check", "--update")
    assert res.exit_code == 0, res.output
    assert (checkout / "data" / "baselines" / "a.json").is_file()
    assert str(checkout / "data") in res.stdout


def test_check_update_refuses_an_installed_copy(runner, tmp_path, radar, monkeypatch):
    data, _ = radar
    installed = tmp_path / "lib" / "python3" / "site-packages" / "replay_data"
    (installed / "baselines").mkdir(parents=True)
    shutil.copy(data, installed / "a.mcap")
    res = invoke(runner, "check", installed, "--update")
    assert res.exit_code == 2 and res.output.count("\n") == 1, res.output
    assert "installed package" in res.output and "pass the data folder" in res.output
    assert not (installed / "baselines" / "a.json").exists()
    monkeypatch.setattr(cli_eval, "bundled_data_dir", lambda: installed)  # the default, outside a checkout
    res = invoke(runner, "check", "--update")
    assert res.exit_code == 2 and "installed package" in res.output
    assert invoke(runner, "check", installed).exit_code == 0  # reading it is fine


def test_cep_plane_writes_under_replay_out(runner, tmp_path):
    res = invoke(runner, "cep-plane", "--geometry", "triangle", "--extent-km", "2", "--step-m", "1000")
    assert res.exit_code == 0, res.output
    assert (tmp_path / "replay-out" / "cep-plane-triangle.png").is_file()
    assert (tmp_path / "replay-out" / "cep-plane-triangle.rrd").is_file()
    assert not list(tmp_path.glob("cep-plane-*"))


def test_eval_export_says_where_it_wrote(runner, tmp_path, radar):
    data, _ = radar
    res = invoke(runner, "eval", data, "--export", "tables")
    assert res.exit_code == 0, res.output
    assert f"written to {Path('tables')}/" in res.stdout and "metrics.csv" in res.stdout and "report.png" in res.stdout
    res = invoke(runner, "eval", data, "--export", "t2", "--json")
    assert res.exit_code == 0
    json.loads(res.stdout)  # stdout stays JSON; the paths went to stderr
    assert "written to t2/" in res.stderr and "metrics.csv" in res.stderr


def test_default_folder_is_never_overwritten_but_numbered(runner, tmp_path, radar):
    data, _ = radar
    for k, folder in enumerate(("radar", "radar-2", "radar-3")):
        res = invoke(runner, data, "--no-rrd")
        assert res.exit_code == 0, res.output
        assert (tmp_path / "replay-out" / folder / "tracks.mcap").is_file()
        if k:
            # the message is wrapped at the table width, where a long temporary path moves the breaks
            assert f"writing to {tmp_path / 'replay-out' / folder}" in " ".join(res.stdout.split())
    res = invoke(runner, data, "--no-rrd", "--force")  # reuses the default folder
    assert res.exit_code == 0 and not (tmp_path / "replay-out" / "radar-4").exists()


def test_a_named_out_folder_with_a_replay_needs_force(runner, tmp_path, radar, sha):
    data, _ = radar
    out = tmp_path / "o" / "tracks.mcap"
    assert invoke(runner, data, "--no-rrd", "--out", out).exit_code == 0
    before = sha(out)
    res = invoke(runner, data, "--no-rrd", "--out", out, "--set", "nominal_cross_range_m=60")
    assert res.exit_code == 2 and res.output.count("\n") == 1 and "--force" in res.output, res.output
    assert sha(out) == before
    res = invoke(runner, data, "--no-rrd", "--out", out, "--set", "nominal_cross_range_m=60", "--force")
    assert res.exit_code == 0 and sha(out) != before
    # an empty folder, or one holding other files, needs nothing
    (tmp_path / "p").mkdir()
    (tmp_path / "p" / "notes.txt").write_text("mine")
    assert invoke(runner, data, "--no-rrd", "--out", tmp_path / "p" / "tracks.mcap").exit_code == 0
    help_text = " ".join(invoke(runner, "run", "--help").output.split())
    assert "--force" in help_text and "-2/" in help_text and "needs --force" in help_text


# --------------------------------------------------------------------------- discoverability


def test_scenario_parameters_show_meaning_unit_and_default(runner, tmp_path):
    res = invoke(runner, "scenarios", "radar-tws")
    assert res.exit_code == 0, res.output
    rows = {line.split()[0]: line for line in res.stdout.splitlines() if line.strip()}
    assert rows["sigma_bearing_deg"].split()[1:3] == ["1", "deg"] and "plot noise, bearing" in rows["sigma_bearing_deg"]
    assert rows["design_sigma_v_mps2"].split()[2] == "m/s²"
    assert rows["scan_period_s"].split()[1:3] == ["5", "s"] and "12 rpm" in rows["scan_period_s"]
    res = invoke(runner, "scenarios", "tdoa-fdoa")
    rows = {line.split()[0]: line.split() for line in res.stdout.splitlines() if line.strip()}
    assert rows["sensor_positions_m"][1] == "(none)" and rows["sigma_fdoa_hz"][2] == "Hz"
    toml = tmp_path / "mine.toml"
    toml.write_text('name = "mine"\nrecorder = "radar-tws"\n[params]\nn_scans = 10   # a short "#" run\n'
                    'sigma_range_m = 50.0  # my radar\n')
    res = invoke(runner, "scenarios", toml)
    assert res.exit_code == 0, res.output
    rows = {line.split()[0]: line for line in res.stdout.splitlines() if line.strip()}
    assert rows["n_scans"].split()[1] == "10" and 'a short "#" run' in rows["n_scans"]
    assert rows["sigma_range_m"].split()[1:3] == ["50", "m"] and "my radar" in rows["sigma_range_m"]
    # parameters the file leaves out take the recorder's bundled defaults
    assert rows["sigma_bearing_deg"].split()[1:3] == ["1", "deg"]
    listing = invoke(runner, "scenarios").stdout
    assert "radar-tws" in listing and "replay scenarios NAME" in listing
    assert max(len(line) for line in listing.splitlines()) <= 100


def test_every_command_help_has_an_example(runner):
    def walk(group, path):
        for name, cmd in group.commands.items():
            yield [*path, name], cmd
            if hasattr(cmd, "commands"):
                yield from walk(cmd, [*path, name])

    seen = 0
    for path, _ in walk(main, []):
        res = invoke(runner, *path, "--help")
        assert res.exit_code == 0 and "Example" in res.output, path
        assert "--quiet" in res.output, path
        seen += 1
    assert seen >= 20 and "Example" in invoke(runner, "--help").output


# --------------------------------------------------------------------------- tables


def test_colored_replay_prints_each_result_once(runner, tmp_path):
    sets = ["--set", "n_samples=240", "--set", "manoeuvre_first_sample=80", "--set", "manoeuvre_last_sample=160"]
    assert invoke(runner, "simulate", "colored-imm", "--runs", 2, "-o", "imm.mcap", *sets).exit_code == 0
    res = invoke(runner, "imm.mcap", "--no-rrd")
    assert res.exit_code == 0, res.output
    out = res.stdout
    assert "[overall]" in out and "rmse_position_m" in out  # the generic table
    # the thesis's layouts repeat its scopes: in report.txt, not printed a second time
    for layout in ("RMSE [", "mean model probability", "AR(1) estimator"):
        assert layout not in out
    folder = next(tmp_path.glob("replay-out/imm*"))
    layouts = (folder / "report.txt").read_text()
    assert "mean model probability" in layouts and "AR(1) estimator" in layouts
    assert "PIMM vs MIMM_K" in out  # a line the tables do not show
    assert max(len(line) for line in out.splitlines()) <= 100


def test_an_empty_scope_is_named(runner, radar):
    data, _ = radar
    res = invoke(runner, data, "--no-rrd", "--set", "nominal_cross_range_m=5000")
    assert res.exit_code == 0, res.output
    lines = res.stdout.splitlines()
    at = lines.index("[cross_range_above_nominal]")
    assert lines[at + 1].startswith("(empty")


def test_emitter_table_fits_100_columns(runner, tmp_path):
    assert invoke(runner, "simulate", "tdoa-fdoa", "--runs", 20, "-o", "e.mcap").exit_code == 0
    res = invoke(runner, "e.mcap", "--no-rrd")
    assert res.exit_code == 0, res.output
    assert max(len(line) for line in res.stdout.splitlines()) <= 100
    text = (next(tmp_path.glob("replay-out/e*")) / "report.txt").read_text()
    assert "RMSE pos m" in text and "RMSE vel" in text and "runs by class" in text
    assert "runs by class" not in res.stdout  # the [overall] table shows them


def test_fit_width_splits_a_wide_table_keeping_columns_whole():
    rows = ["name      " + "".join(f"{'col ' + str(i):>12}" for i in range(10)),
            "-" * 130,
            "alpha     " + "".join(f"{i * 1.5:>12.3f}" for i in range(10)),
            "beta      " + "".join(f"{'nan':>12}" for _ in range(10))]
    out = cli_text.fit_width("\n".join(rows), 100)
    lines = out.splitlines()
    assert max(len(line) for line in lines) <= 100
    assert sum(line.startswith("name") for line in lines) == 2 and sum(line.startswith("alpha") for line in lines) == 2
    assert all(f"col {i}" in out for i in range(10)) and "13.500" in out
    prose = cli_text.fit_width("word " * 40, 100)
    assert max(len(line) for line in prose.splitlines()) <= 100


# --------------------------------------------------------------------------- export


def _read_json_mcap(path):
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        schemas = {sid: s for sid, s in summary.schemas.items()}
        channels = {c.topic: c for c in summary.channels.values()}
        messages = {}
        for _, channel, message in reader.iter_messages():
            messages.setdefault(channel.topic, []).append((message.log_time, message.publish_time,
                                                           json.loads(message.data)))
    return schemas, channels, messages


def test_foxglove_export_is_plain_json_in_mcap(runner, tmp_path, radar):
    data, tracks = radar
    res = invoke(runner, "export", "--foxglove", tracks, "-o", "view.mcap", "--data", data)
    assert res.exit_code == 0, res.output
    assert "view.mcap" in res.stdout and "runs 0–9 of 12" in res.stdout
    schemas, channels, messages = _read_json_mcap(tmp_path / "view.mcap")
    trackers = {"fixed", "approximate", "exact", "kalman"}
    runs = {t.split("/")[1] for t in channels if t.startswith("/run_")}
    assert runs == {f"run_{r:03d}" for r in range(10)}  # the first 10 runs by default
    assert {t.split("/")[2] for t in channels if t.startswith("/run_000/")} == trackers | {"truth"}
    assert {t.split("/")[2] for t in channels if t.startswith("/metrics/")} == trackers
    for channel in channels.values():
        schema = schemas[channel.schema_id]
        assert channel.message_encoding == "json" and schema.encoding == "jsonschema"
        doc = json.loads(schema.data)
        assert doc["type"] == "object" and {"t", "scan"} <= set(doc["properties"])
    kalman = messages["/run_003/kalman"]
    assert len(kalman) == 16
    doc = json.loads(schemas[channels["/run_003/kalman"].schema_id].data)
    assert {"x", "y", "vx", "vy", "sd_x", "flags"} <= set(doc["properties"])
    for log_time, publish_time, msg in kalman:
        assert log_time == publish_time == round(msg["t"] * 1e9)  # scan time, no offset
        assert msg["run"] == 3 and isinstance(msg["flags"], int)
    last = kalman[-1][2]
    assert all(isinstance(last[k], float) for k in ("x", "y", "vx", "vy"))
    truth = messages["/run_003/truth"][-1][2]
    assert abs(truth["x"] - last["x"]) < 2000  # the track is near its truth
    # the metrics are the replay's per-scan metrics
    import polars as pl

    from trackreplay.replay import evaluate_files

    per_scan = evaluate_files(data, tracks).per_scan.filter(pl.col("tracker") == "kalman").sort("scan")
    rmse = [m["rmse_position_m"] for _, _, m in messages["/metrics/kalman"]]
    expected = [None if v is None or v != v else v for v in per_scan["rmse_position_m"].to_list()]
    assert [r is None for r in rmse] == [v is None for v in expected] and any(v is not None for v in expected)
    assert [r for r in rmse if r is not None] == pytest.approx([v for v in expected if v is not None], rel=1e-12)


def test_foxglove_export_runs_and_refusals(runner, tmp_path, radar, sha):
    data, tracks = radar
    res = invoke(runner, "export", "--foxglove", tracks, "-o", "v.mcap", "--runs", "0,2", "--data", data)
    assert res.exit_code == 0, res.output
    _, channels, _ = _read_json_mcap(tmp_path / "v.mcap")
    assert {t.split("/")[1] for t in channels if t.startswith("/run_")} == {"run_000", "run_002"}
    before = sha(tracks)
    res = invoke(runner, "export", "--foxglove", tracks, "-o", tracks)
    assert res.exit_code == 2 and "over the input" in res.output and sha(tracks) == before
    res = invoke(runner, "export", "--foxglove", tracks, "-o", "w.mcap", "--runs", "40")
    assert res.exit_code == 2 and "runs 0–11" in res.output and not (tmp_path / "w.mcap").exists()
    res = invoke(runner, "export", tracks, "-o", "w.mcap")
    assert res.exit_code == 2 and "--foxglove" in res.output
    # without the data set (not found beside the outputs): tracks only, and a note says why
    lone = tmp_path / "lone" / "tracks.mcap"
    lone.parent.mkdir()
    shutil.copy(tracks, lone)
    res = invoke(runner, "export", "--foxglove", lone, "-o", "lone.mcap")
    assert res.exit_code == 0 and "note: no truth or per-scan metrics" in res.stdout, res.output
    _, channels, _ = _read_json_mcap(tmp_path / "lone.mcap")
    assert not [t for t in channels if t.startswith("/metrics") or t.endswith("/truth")]


# --------------------------------------------------------------------------- viewing a data set


def test_view_of_a_data_set_opens_the_recording_of_its_replay(runner, tmp_path, monkeypatch, radar):
    """`replay view DATA.mcap` shows the family's views (a recording with the tracks, built in a
    scratch folder), not the raw file the viewer would show as an empty view."""
    import trackreplay.face.viewer as viewer

    data, _ = radar
    opened = []
    monkeypatch.setattr(viewer, "open_viewer", lambda path: opened.append(Path(path)))
    before = sorted(p.name for p in data.parent.iterdir())
    res = invoke(runner, "view", data)
    assert res.exit_code == 0, res.output
    assert len(opened) == 1 and opened[0].suffix == ".rrd" and opened[0].parent != data.parent
    assert opened[0].read_bytes()[:3] == viewer.RRD_MAGIC  # a Rerun recording
    assert sorted(p.name for p in data.parent.iterdir()) == before  # nothing written beside the data


def test_view_of_a_replay_output_without_its_recording_says_what_to_do(runner, tmp_path, radar):
    from trackreplay.replay import replay

    data, _ = radar
    out = tmp_path / "r" / "tracks.mcap"
    replay(data, out_path=out)
    res = invoke(runner, "view", out)
    assert res.exit_code == 2
    assert res.output.count("\n") == 1 and "without its recording" in res.output


def test_on_a_pseudo_terminal_bars_go_to_stderr_and_json_stays_pure(tmp_path, radar):
    """A real terminal on stderr (not a patched check): the bar is drawn there, stdout stays
    parseable JSON, and --quiet silences the terminal."""
    import os
    import pty
    import subprocess
    import sys

    data, _ = radar

    def run(*extra):
        leader, follower = pty.openpty()
        try:
            done = subprocess.run([sys.executable, "-c", "from trackreplay.face.cli import main; main()", "eval", str(data),
                                   "--json", *extra], stdout=subprocess.PIPE, stderr=follower, cwd=tmp_path,
                                  timeout=120, env={**os.environ, "COLUMNS": "100"})
            os.close(follower)
            drawn = b""
            while True:
                try:
                    chunk = os.read(leader, 65536)
                except OSError:  # the terminal closed with the child
                    break
                if not chunk:
                    break
                drawn += chunk
        finally:
            os.close(leader)
        return done, drawn.decode("utf-8", "replace")

    done, terminal = run()
    assert done.returncode == 0
    json.loads(done.stdout)
    assert f"evaluating {data.name}" in terminal and "[####" in terminal, terminal[:200]
    done, terminal = run("--quiet")
    assert done.returncode == 0
    json.loads(done.stdout)
    assert terminal.strip() == ""


def test_run_options_may_come_before_the_data_file(runner, radar, tmp_path):
    data, _ = radar
    res = invoke(runner, "--no-rrd", "--rerun-run", 3, data, "--out", tmp_path / "o" / "tracks.mcap", "--figures",
                 "none")
    assert res.exit_code == 0, res.output
    assert (tmp_path / "o" / "tracks.mcap").is_file() and not (tmp_path / "o" / "tracks.rrd").exists()


def test_a_rerun_run_past_the_last_run_is_said_and_the_last_run_shown(runner, radar, tmp_path):
    data, _ = radar
    res = invoke(runner, data, "--rerun-run", 99, "--out", tmp_path / "o" / "tracks.mcap", "--figures", "none")
    assert res.exit_code == 0, res.output
    assert "--rerun-run 99: radar.mcap holds runs 0–11; the Rerun views show run 11" in res.output


def test_a_file_with_no_complete_chunk_does_not_suggest_recover(runner, radar, tmp_path):
    data, _ = radar
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data.read_bytes()[:100])
    res = invoke(runner, cut)
    assert res.exit_code == 2 and "no complete chunk survives, so --recover has nothing to keep" in res.output
