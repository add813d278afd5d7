"""The sweep's output folder: the files a point writes (removed again when it fails), the
temporaries a killed sweep leaves, the lock a running sweep holds, and writes whose errors name
their file."""

from __future__ import annotations

import os
import re
from contextlib import contextmanager
from pathlib import Path

from trackreplay.contract import atomic_output
from trackreplay.errors import InputError


#: what a point writes into its folder (with --keep-data): removed again when the point fails
POINT_FILES = ("data.mcap", "tracks.mcap", "tracks.rrd")


def _point_files(folder: Path) -> dict:
    """What a point's folder holds of :data:`POINT_FILES` now: whether it exists, and each file's
    identity (inode, modification time, size), to tell later which files a run put there."""
    files = {}
    for name in POINT_FILES:
        try:
            st = (folder / name).stat()
        except OSError:
            continue
        files[name] = (st.st_ino, st.st_mtime_ns, st.st_size)
    return {"folder": folder.is_dir(), "files": files}


def discard_point_files(folder, before: dict | None) -> list[Path]:
    """Remove what a failed or stopped point wrote into ``folder``: each of :data:`POINT_FILES`
    that is not the file ``before`` (:func:`_point_files` taken before the point ran) saw, their
    half-written temporaries, and the folder when the point made it and it is left empty. Files
    the point did not write stay, whatever their names."""
    folder = Path(folder)
    before = before or {"folder": False, "files": {}}
    now = _point_files(folder)
    removed = []
    for name, identity in now["files"].items():
        if before["files"].get(name) != identity:
            try:
                (folder / name).unlink()
                removed.append(folder / name)
            except OSError:
                pass
    try:
        entries = list(folder.iterdir()) if now["folder"] else []
    except OSError:
        entries = []
    for f in entries:
        if _TEMPORARY.fullmatch(f.name) and f.name.startswith(tuple(n + "." for n in POINT_FILES)):
            try:
                f.unlink()
                removed.append(f)
            except OSError:
                pass
    if now["folder"] and not before["folder"]:
        try:
            folder.rmdir()  # only when empty
        except OSError:
            pass
    return removed


def _metrics_file(out_dir: Path, label: str) -> Path:
    return out_dir / "points" / label / "metrics.parquet"


def _record_file(out_dir: Path, label: str) -> Path:
    return out_dir / "points" / label / "point.json"


_TEMPORARY = re.compile(r".+\.[A-Za-z0-9_]{8}\.tmp$")  # atomic_output's mkstemp names


def _remove_temporaries(out_dir: Path) -> list[Path]:
    """Remove the half-written files (``<name>.<random>.tmp``) a killed sweep left in the
    folder: beside the table, in ``plots/`` and in every ``points/<label>/``."""
    dirs = [out_dir, out_dir / "plots"]
    points = out_dir / "points"
    if points.is_dir():
        dirs += [d for d in points.iterdir() if d.is_dir()]
    removed = []
    for d in dirs:
        try:
            entries = list(d.iterdir())
        except OSError:
            continue
        for f in entries:
            if _TEMPORARY.fullmatch(f.name) and f.is_file():
                try:
                    f.unlink()
                    removed.append(f)
                except OSError:
                    pass
    return removed


@contextmanager
def _folder_lock(out_dir: Path | None):
    """Hold an exclusive lock on the output folder (released by the kernel however the process
    ends), so that removing temporaries never races another sweep writing there."""
    if out_dir is None:
        yield
        return
    try:
        import fcntl
    except ImportError:  # not POSIX
        yield
        return
    out_dir.mkdir(parents=True, exist_ok=True)
    fd = os.open(out_dir, os.O_RDONLY)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise InputError("another sweep is writing to this folder; wait for it or choose another -o",
                             out_dir) from None
        yield
    finally:
        os.close(fd)


@contextmanager
def _named_output(path: Path, mode: str = "wb"):
    """:func:`~trackreplay.contract.atomic_output`, whose errors name the file: a write that fails
    (a full disk) raises an ``OSError`` without a file name, and the user's line must name it."""
    try:
        with atomic_output(path, mode) as fh:
            yield fh
    except OSError as exc:
        if exc.filename is None and exc.errno is not None:
            raise OSError(exc.errno, exc.strerror or str(exc), str(path)) from None
        raise
