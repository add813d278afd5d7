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
