"""Output paths that must never replace an input.

Every command names its inputs and the outputs it is about to write; any output that resolves
to an input (the same file, also through symbolic or hard links, or a folder output that holds
an input that would be written over) is refused before anything is written.
"""

from __future__ import annotations

import os
from pathlib import Path

from pipeline.errors import InputError


def _same(a: Path, b: Path) -> bool:
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
    except OSError:
        pass
    return a.resolve() == b.resolve()


def refuse_input_overwrite(inputs, outputs) -> None:
    """Raise :class:`InputError` when an output path is one of the inputs.

    Parameters
    ----------
    inputs : iterable of path-like
        Files the command reads.
    outputs : iterable of path-like
        Files the command will write (None entries are ignored).
    """
    ins = [Path(p) for p in inputs if p is not None]
    for out in outputs:
        if out is None:
            continue
        out = Path(out)
        for src in ins:
            if _same(src, out):
                raise InputError(f"refusing to write an output over the input {src} (choose another output path)", out)


def refuse_replacing_file(output, force: bool) -> None:
    """Raise :class:`InputError` when ``output`` exists and ``force`` was not given: a file a
    command writes replaces an earlier one only when asked (``--force``)."""
    output = Path(output)
    if output.exists() and not force:
        raise InputError("exists; add --force to replace it, or choose another output path", output)


class OutputSet:
    """A folder's outputs written as a set: all of them appear, or none.

    Everything is first written into a hidden staging folder inside ``folder``; when the block
    ends without an error the files are moved into place (``os.replace``: each move is atomic,
    and they follow each other within microseconds), files of the previous set that this one does
    not produce (``replaces``) are removed unless the command reads them (``inputs``), and the
    staging folder goes. On an error, or if the
    process is killed, the previous set stays as it was; a staging folder left by a killed
    process is removed by the next run.

    Example
    -------
    >>> with OutputSet(out_dir, replaces=["tracks.rrd"]) as outputs:     # doctest: +SKIP
    ...     write(outputs.path("tracks.mcap"))
    """

    PREFIX = ".partial-"

    def __init__(self, folder, replaces=(), inputs=()):
        self.folder = Path(folder)
        self.replaces = list(replaces)
        # files this command reads: never removed, whatever their names (an input called
        # tracks.rrd is not a stale recording)
        self.inputs = [Path(p) for p in inputs if p is not None]
        self.stage: Path | None = None

    def __enter__(self) -> "OutputSet":
        # folders this set creates, removed again (when empty) if it fails
        self.created = []
        for folder in [self.folder, *self.folder.parents]:
            if folder.exists():
                break
            self.created.append(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.clean_stale()
        self.stage = self.folder / f"{self.PREFIX}{os.getpid()}"
        if self.stage.exists():
            _remove_tree(self.stage)
        self.stage.mkdir()
        return self

    def path(self, name: str) -> Path:
        """Where to write the output ``name`` now (it is moved to ``folder / name`` at the end)."""
        return self.stage / name

    def final(self, staged: Path) -> Path:
        """The final place of a staged path."""
        return self.folder / Path(staged).relative_to(self.stage)

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc_type is not None:
            _remove_tree(self.stage)
            for folder in self.created:  # innermost first
                try:
                    folder.rmdir()
                except OSError:
                    break
            return False
        produced = sorted(p for p in self.stage.rglob("*") if p.is_file())
        for p in produced:
            target = self.final(p)
            target.parent.mkdir(parents=True, exist_ok=True)
            os.replace(p, target)
        names = {self.final(p).name for p in produced}
        for name in self.replaces:
            old = self.folder / name
            if name not in names and old.is_file() and not any(_same(old, src) for src in self.inputs):
                old.unlink()
        _remove_tree(self.stage)
        return False

    def clean_stale(self) -> None:
        """Remove staging folders of processes that no longer run (killed mid-write)."""
        for p in self.folder.glob(f"{self.PREFIX}*"):
            pid = p.name[len(self.PREFIX):]
            if not pid.isdigit() or not _alive(int(pid)) or int(pid) == os.getpid():
                _remove_tree(p)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _remove_tree(path: Path) -> None:
    import shutil

    shutil.rmtree(path, ignore_errors=True)
