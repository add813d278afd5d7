"""``replay convert upgrade``: rewrite an MCAP file of an older contract in the current one.

Registered under the existing ``replay convert`` group (this module is listed in
``trackreplay.face.cli.EXTENSION_MODULES``; its CONVERT_COMMANDS join the group).
"""

from __future__ import annotations

from pathlib import Path

import click

COMMANDS: list = []  # no top-level command


@click.command("upgrade")
@click.argument("src", type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False, path_type=Path),
              help="The rewritten file (never SRC itself: an input is never written over).")
@click.option("--recover", is_flag=True, help="Keep the intact chunks of a truncated or damaged file.")
@click.option("--force", is_flag=True, help="Replace the output file if it exists.")
def upgrade_cmd(src, output, recover, force):
    """Rewrite a replay.v1 (or any) data set in the current contract (replay.v2).

    Every frame, array and metadata record is kept exactly (the scenario record's `contract`
    field names the new contract); v2 stores one message per channel and scan carrying every
    run, which reads many times faster.

    \b
    Example:
      replay convert upgrade old.mcap -o new.mcap
      replay convert upgrade cut.mcap -o kept.mcap --recover
    """
    from trackreplay.contract import rewrite_dataset
    from trackreplay.paths import refuse_input_overwrite, refuse_replacing_file

    refuse_input_overwrite([src], [output])
    refuse_replacing_file(output, force)
    rep = rewrite_dataset(src, output, recover=recover)
    was = ", ".join(rep.source_contracts) or "no frames"
    click.echo(f"wrote {output}: {rep.frames} frames, {rep.messages_in} messages ({was}) → {rep.messages_out} "
               f"messages ({rep.contract})")
    if rep.problem:
        click.echo(f"recovered the intact chunks of {src}: {rep.problem}")


CONVERT_COMMANDS = [upgrade_cmd]  # added under `replay convert` by trackreplay.face.cli
