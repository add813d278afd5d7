"""Output paths that must never replace an input.

Every command names its inputs and the outputs it is about to write; any output that resolves
to an input (the same file, also through symbolic or hard links, or a folder output that holds
an input that would be written over) is refused before anything is written.
"""

from __future__ import annotations

import os
from pathlib import Path

from trackreplay.errors import InputError


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
    """A folder's outputs written as a set, published with one rename: a reader of the folder
    sees the complete previous set or the complete new one at every instant, never a mix.

    How (one atomic rename, and why this one): every output ``NAME`` of the set is a relative
    symbolic link ``NAME -> .<set>-current/NAME``, and ``.<set>-current`` is itself a link to
    the hidden version folder that holds the files (``.<set>-v<pid>-<token>/``). A run writes
    its whole set into a new version folder, makes sure every name it produces has its link
    (a link to a name the current version lacks dangles, so the name still reads as absent),
    and then publishes by renaming a fresh ``.<set>-current`` link over the old one. POSIX
    ``rename`` replaces the link atomically, so every path of the folder switches at that one
    instant; afterwards the links of names the new set lacks (dangling now) and the previous
    version folder are removed. The alternatives were weaker here: moving files one rename at a
    time is a mix while it lasts (and the audit of issue 30 hit it in 17 of 30 timed kills);
    swapping the whole folder (a folder behind a link, or Linux ``renameat2(RENAME_EXCHANGE)``)
    would take the user's other files in that folder with it, inputs included; a manifest written
    last is only atomic for readers that consult it, not for ``ls``, a viewer or a script.

    Nothing a run did not create is removed: only links of this set's own form
    (``.<set>-current/NAME``) and this set's own hidden folders are ever deleted. A regular file
    (or someone else's link) at a name this run produces is replaced only by the name's link to
    identical bytes first (a hard link of the file in the current version, so a reader sees no
    change until the rename), and the caller refuses that beforehand unless the user asked to
    replace earlier outputs (``--force``); the inputs (``inputs``) are never replaced, and a
    version folder holding one is kept. Regular files at other names stay, however they are
    named. What a killed run left (version folders of processes that no longer run, half-made
    links, dangling links of this set) is removed by the next run, which reports it in one line
    through ``say``. On a file system without symbolic links the files are moved into place one
    ``os.replace`` at a time, as before (each file whole, the set not at one instant).
    ``docs/architecture.md`` (step 7, "Write") describes the layout for users.

    Parameters
    ----------
    folder : path-like
        Where the outputs appear (created with its parents if missing; removed again, when
        empty, if the run fails).
    replaces : iterable of str
        Names of an earlier set that this one may not produce (e.g. ``tracks.rrd`` after a
        replay with ``--no-rrd``): their links go when the new set is published; a regular
        file with such a name is never removed (it may be the user's) and is named through
        ``say``.
    inputs : iterable of path-like
        Files the command reads: never replaced or removed, whatever their names.
    name : str
        The set's name in its hidden entries, so two commands' sets in one folder (a replay's,
        an export's) never take each other's files.
    say : callable, optional
        Receives the one-line notes (leftovers removed, files kept); default: none are given.

    Example
    -------
    >>> with OutputSet(out_dir, replaces=["tracks.rrd"], inputs=[data]) as outputs:  # doctest: +SKIP
    ...     write(outputs.path("tracks.mcap"))
    """

    PREFIX = ".partial-"  # the staging folders of earlier versions of this class (cleaned too)

    def __init__(self, folder, replaces=(), inputs=(), name: str = "outputs", say=None):
        self.folder = Path(folder)
        self.replaces = list(replaces)
        self.inputs = [Path(p) for p in inputs if p is not None]
        self.name = name
        self.say = say or (lambda line: None)
        self.stage: Path | None = None

    # the hidden entries of this set, all in ``folder``
    @property
    def current(self) -> Path:
        """The link that names the published version folder."""
        return self.folder / f".{self.name}-current"

    def _own(self, kind: str) -> str:
        """The name prefix of this set's hidden entries of one kind (v: versions, l: link
        being made) made by this process."""
        return f".{self.name}-{kind}{os.getpid()}-"

    def __enter__(self) -> "OutputSet":
        # folders this set creates, removed again (when empty) if it fails
        self.created = []
        for folder in [self.folder, *self.folder.parents]:
            if folder.exists() or folder.is_symlink():
                break
            self.created.append(folder)
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            self.clean_stale()
            self.stage = self.folder / f"{self._own('v')}{os.urandom(4).hex()}"
            self.stage.mkdir()
        except OSError as exc:  # a read-only or full disk: named by the folder the user gave
            self.stage = None
            self._abandon()
            raise OSError(exc.errno, exc.strerror or str(exc), str(self.folder)) from None
        return self

    def path(self, name: str) -> Path:
        """Where to write the output ``name`` now (it appears as ``folder / name`` at the end)."""
        return self.stage / name

    def final(self, staged: Path) -> Path:
        """The final place of a staged path."""
        return self.folder / Path(staged).relative_to(self.stage)

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc_type is None:
            try:
                self._publish()
                return False
            except OSError as failed:
                named = self._named(failed)
                self._abandon()
                raise named from None
            except BaseException:
                self._abandon()
                raise
        named = self._named(exc) if isinstance(exc, OSError) else None
        self._abandon()
        if named is not None and named is not exc:
            raise named from None
        return False

    def _named(self, exc: OSError) -> OSError:
        """``exc`` naming the output the user asked for: a staged path becomes its final one,
        and a failure that names no file (a full disk under a writer of an open file) names the
        output being written (the staged file changed last), else the folder."""
        filename = exc.filename
        if filename is None and self.stage is not None and self.stage.is_dir():
            staged = [p for p in self.stage.rglob("*") if p.is_file()]
            filename = max(staged, key=lambda p: p.stat().st_mtime_ns) if staged else self.folder
        if filename is None:
            filename = self.folder
        filename = Path(filename)
        if self.stage is not None and _inside(filename, self.stage):
            rel = Path(os.path.realpath(filename)).relative_to(os.path.realpath(self.stage))
            filename = self.folder / rel if str(rel) != "." else self.folder
            if filename.name.endswith(".tmp") and filename.name.count(".") >= 3:  # an atomic writer's NAME.XXXX.tmp
                filename = filename.with_name(filename.name.rsplit(".", 2)[0])
        elif self.folder is not None and filename.name.startswith(f".{self.name}-"):
            filename = self.folder
        if Path(filename) == Path(exc.filename or "") and exc.filename is not None:
            return exc
        return OSError(exc.errno, exc.strerror or str(exc), str(filename))

    def _abandon(self) -> None:
        """Remove what this run staged, and the folders it created if they are empty."""
        if self.stage is not None and self.stage.exists():
            if not self.current.is_symlink() or os.readlink(self.current) != self.stage.name:
                _remove_tree(self.stage)
        for p in self.folder.glob(f"{self._own('l')}*"):
            _unlink(p)
        for folder in self.created:  # innermost first
            try:
                folder.rmdir()
            except OSError:
                break

    # ------------------------------------------------------------------ publishing

    def _link_target(self, rel: Path) -> str:
        """What the link at ``folder / rel`` points to: ``.<set>-current/rel``, relative to
        the link's own folder."""
        return os.path.relpath(self.current / rel, (self.folder / rel).parent)

    def _is_own_link(self, entry: Path, rel: Path) -> bool:
        return entry.is_symlink() and os.readlink(entry) == self._link_target(rel)

    def _publish(self) -> None:
        produced = sorted(p.relative_to(self.stage) for p in self.stage.rglob("*") if p.is_file() or p.is_symlink())
        if not _symlinks_work(self.folder, self._own("l")):
            self._publish_by_moves(produced)
            return
        _pause("links")
        previous = os.readlink(self.current) if self.current.is_symlink() else None
        # 1. every name this set produces gets its link; a file already there is first carried
        #    into the current version (a hard link: the same bytes), so no reader sees a change yet
        for rel in produced:
            entry = self.folder / rel
            if self._is_own_link(entry, rel):
                continue
            entry.parent.mkdir(parents=True, exist_ok=True)
            if entry.is_symlink() or entry.exists():
                if entry.is_dir() and not entry.is_symlink():
                    raise IsADirectoryError(21, "is a folder; the output of that name cannot replace it", str(entry))
                if any(_same(entry, src) for src in self.inputs):  # callers refuse this first; never here
                    raise InputError("refusing to write an output over an input", entry)
                previous = self._carry_into_current(entry, rel, previous)
            self._replace_with_link(entry, self._link_target(rel))
        # 2. the one rename that publishes the set
        _pause("swap")
        self._replace_with_link(self.current, self.stage.name)
        _pause("swapped")
        # 3. what the previous set had and this one does not: its links (dangling now) go;
        #    regular files stay, named
        kept = []
        names = {str(rel) for rel in produced}
        for rel in self._candidate_names(produced):
            entry = self.folder / rel
            if str(rel) in names:
                continue
            if self._is_own_link(entry, rel):
                _unlink(entry)
            elif str(rel) in self.replaces and entry.is_file() and not entry.is_symlink() \
                    and not any(_same(entry, src) for src in self.inputs):
                kept.append(str(rel))
        if kept:
            self.say(f"kept {', '.join(kept)} in {self.folder}: not written by this run, so not removed (if it "
                     "is an earlier run's output, remove it by hand)")
        # 4. the previous version folder, unless something this command reads lives in it
        if previous is not None and previous != self.stage.name:
            self._remove_version(self.folder / previous)
        _pause("done")

    def _candidate_names(self, produced) -> list:
        """Names whose links may belong to the previous set: the folder's entries (and those
        of the folders the produced names are in) and the declared ``replaces``."""
        out = {Path(n) for n in self.replaces}
        for folder in {self.folder, *(self.folder / rel.parent for rel in produced)}:
            try:
                out |= {p.relative_to(self.folder) for p in folder.iterdir() if p.is_symlink()}
            except OSError:
                pass
        return sorted(out)

    def _carry_into_current(self, entry: Path, rel: Path, previous):
        """Put the bytes ``entry`` shows into the current version folder under ``rel`` (made
        when there is none yet), so that replacing ``entry`` by its link changes nothing a
        reader sees. Returns the current version's folder name."""
        if previous is None:
            previous = f"{self._own('v')}{os.urandom(4).hex()}"
            (self.folder / previous).mkdir()
            self._replace_with_link(self.current, previous)
        kept = self.folder / previous / rel
        kept.parent.mkdir(parents=True, exist_ok=True)
        if not (kept.exists() or kept.is_symlink()):
            if entry.is_symlink():  # someone's link: the same target, reached from the version folder
                os.symlink(os.path.realpath(entry), kept)
            else:
                try:
                    os.link(entry, kept)
                except OSError:  # a file system without hard links
                    import shutil

                    shutil.copy2(entry, kept)
        return previous

    def _replace_with_link(self, entry: Path, target: str) -> None:
        """Make ``entry`` a symbolic link to ``target`` with one atomic rename."""
        _link_atomically(entry, target, f"{self._own('l')}{os.urandom(4).hex()}")

    def _remove_version(self, version: Path) -> None:
        if version.is_dir() and not version.is_symlink() \
                and not any(_inside(src, version) for src in self.inputs):
            _remove_tree(version)

    def _publish_by_moves(self, produced) -> None:
        """Without symbolic links: each file moved into place with its own ``os.replace``."""
        for rel in produced:
            target = self.folder / rel
            target.parent.mkdir(parents=True, exist_ok=True)
            os.replace(self.stage / rel, target)
        _remove_tree(self.stage)

    # ------------------------------------------------------------------ leftovers

    def clean_stale(self) -> None:
        """Remove what runs that no longer run left: version folders that are not published,
        half-made links, this set's dangling links, and staging folders of earlier versions of
        this class; say so in one line."""
        published = os.readlink(self.current) if self.current.is_symlink() else None
        folders, links = 0, 0
        for p in self.folder.iterdir():
            n = p.name
            kind = f".{self.name}-v" if n.startswith(f".{self.name}-v") else self.PREFIX if n.startswith(self.PREFIX) else None
            if kind is not None:
                if n == published or _owner_alive(n, kind) or any(_inside(src, p) for src in self.inputs):
                    continue
                _remove_tree(p)
                folders += 1
            elif n.startswith(f".{self.name}-l") and not _owner_alive(n, f".{self.name}-l"):
                _unlink(p)
                links += 1
            elif p.is_symlink() and self._is_own_link(p, Path(n)) and not p.exists():
                _unlink(p)  # a name of a set that was replaced by one without it
                links += 1
        if published is not None and not (self.folder / published).is_dir():
            _unlink(self.current)
            links += 1
        if folders or links:
            parts = [f"{folders} unfinished output folder(s)" if folders else "",
                     f"{links} dangling link(s)" if links else ""]
            self.say(f"removed what an interrupted run left in {self.folder}: {' and '.join(filter(None, parts))}")


def set_version_folder(member) -> Path | None:
    """The version folder of the :class:`OutputSet` whose output ``member`` is (a link
    ``NAME -> .<set>-current/NAME``), or None when ``member`` is an ordinary file.

    Files added later to a published set (the figures ``replay plot`` draws beside a replay's
    outputs) are written into this folder and linked with :func:`link_into_set`.
    """
    member = Path(member)
    if not member.is_symlink():
        return None
    target = Path(os.readlink(member))
    parts = target.parts
    if len(parts) != 2 or not (parts[0].startswith(".") and parts[0].endswith("-current")):
        return None
    current = member.parent / parts[0]
    if not current.is_symlink():
        return None
    return member.parent / os.readlink(current)


def link_into_set(member, name: str) -> None:
    """Give ``name``, written into the version folder of ``member``'s set, its link beside
    ``member`` (a regular file of that name is replaced by the link only when it is not there)."""
    member = Path(member)
    entry = member.parent / name
    target = str(Path(os.readlink(member)).parent / name)
    if entry.is_symlink() and os.readlink(entry) == target:
        return
    _link_atomically(entry, target, f".link-{os.getpid()}-{os.urandom(4).hex()}")


def _link_atomically(entry: Path, target: str, temporary_name: str) -> None:
    """Make ``entry`` a symbolic link to ``target``: the link is made under ``temporary_name``
    beside it and renamed over ``entry`` (one atomic step; a reader sees the old entry or the new)."""
    tmp = entry.parent / temporary_name
    os.symlink(target, tmp)
    try:
        os.replace(tmp, entry)
    except BaseException:
        _unlink(tmp)
        raise


def _symlinks_work(folder: Path, prefix: str) -> bool:
    """Whether ``folder``'s file system takes symbolic links (not FAT, not Windows without the
    privilege)."""
    probe = folder / f"{prefix}probe"
    try:
        os.symlink("probe", probe)
    except (OSError, NotImplementedError):
        return False
    _unlink(probe)
    return True


def _owner_alive(name: str, prefix: str) -> bool:
    """Whether the process whose id follows ``prefix`` in ``name`` still runs (and is not this one)."""
    pid = name[len(prefix):].split("-", 1)[0]
    return pid.isdigit() and int(pid) != os.getpid() and _alive(int(pid))


def _inside(path: Path, folder: Path) -> bool:
    try:
        Path(os.path.realpath(path)).relative_to(os.path.realpath(folder))
        return True
    except ValueError:
        return False


def _unlink(path: Path) -> None:
    try:
        os.unlink(path)
    except FileNotFoundError:
        pass


def _pause(step: str) -> None:
    """A test hook at each step of publishing: with ``TRACKREPLAY_PUBLISH_TRACE`` set, append
    the step's name to that file and sleep ``TRACKREPLAY_PUBLISH_PAUSE_S`` seconds, so that a
    test can kill the process exactly there (``tests/test_output_sets.py``)."""
    trace = os.environ.get("TRACKREPLAY_PUBLISH_TRACE")
    if not trace:
        return
    import time

    with open(trace, "a") as f:
        f.write(step + "\n")
    time.sleep(float(os.environ.get("TRACKREPLAY_PUBLISH_PAUSE_S", "0")))


def remove_stale_temporaries(output) -> list[Path]:
    """Remove the temporaries ``NAME.<pid>.<random>.tmp`` that a killed writer of ``output`` left
    beside it (their process no longer runs); returns what was removed."""
    output = Path(output)
    removed = []
    for tmp in output.parent.glob(f"{output.name}.*.tmp"):
        pid = tmp.name[len(output.name) + 1:].split(".", 1)[0]
        if pid.isdigit() and int(pid) != os.getpid() and not _alive(int(pid)) and tmp.is_file():
            try:
                tmp.unlink()
                removed.append(tmp)
            except OSError:  # another process's, or gone already: not ours to insist on
                pass
    return removed


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


# ---------------------------------------------------------------------- a full or read-only disk

#: errno values that say the file system refused a write (full, over quota, over the size limit
#: a process may write, read-only), as opposed to a problem with the input
DISK_ERRNOS = frozenset(e for e in (getattr(__import__("errno"), n, None) for n in
                                    ("ENOSPC", "EDQUOT", "EFBIG", "EROFS", "EACCES", "EPERM", "EIO")) if e is not None)


def disk_error(exc: BaseException, path) -> OSError | None:
    """The file system's failure while writing ``path``, as an :class:`OSError` that names
    ``path``; None when ``exc`` is something else.

    Writers that write into an open file (an MCAP writer, polars, matplotlib) or in a thread
    of their own (Rerun's file sink) report a full disk without the file's name: an
    ``OSError`` whose ``filename`` is None (or the temporary file next to ``path``), or
    Rerun's ``RuntimeError`` "Failed to write: No space left on device (os error 28)" or "File-writer
    thread shut down prematurely". The command line words an ``OSError`` as
    ``replay: error: <file>: <problem>``, so this names the output the user asked for.
    """
    import errno

    path = os.fspath(path)
    if isinstance(exc, OSError):
        if exc.filename is not None and not _beside(exc.filename, path):
            return None
        return OSError(exc.errno, exc.strerror or str(exc), path)
    if isinstance(exc, RuntimeError):
        text = str(exc)
        import re

        code = re.search(r"os error (\d+)", text)
        if code:
            number = int(code.group(1))
            return OSError(number, os.strerror(number), path)
        if "File-writer thread shut down prematurely" in text or "file sink" in text.lower():
            return stalled_writer_error(path, "the Rerun writer stopped")
    return None


def stalled_writer_error(path, what: str) -> OSError:
    """An :class:`OSError` naming ``path`` for a writer that stopped or stalled (``what``), with
    the cause the file system shows: no space left, read-only, or neither."""
    import errno

    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    try:
        st = os.statvfs(folder)
        full = st.f_bavail * st.f_frsize < 64 * 1024
        read_only = bool(st.f_flag & os.ST_RDONLY)
    except (OSError, AttributeError):
        full = read_only = False
    if read_only:
        return OSError(errno.EROFS, f"{os.strerror(errno.EROFS)} ({what})", path)
    if full:
        return OSError(errno.ENOSPC, f"{os.strerror(errno.ENOSPC)} ({what})", path)
    return OSError(errno.EIO, f"{what} without writing it (is its disk full or failing?)", path)


#: How long a stalled writer is given when its disk is full or read-only before it counts as failed.
DISK_GRACE_S = 2.0


def _refuses_writes(path) -> bool:
    """Whether the file system of ``path``'s folder is full (under 64 KiB free) or read-only."""
    return stalled_writer_error(path, "").errno != __import__("errno").EIO


def _beside(filename, path: str) -> bool:
    """``filename`` is ``path`` or a temporary file made next to it (``<name>.XXXX.tmp``)."""
    filename = os.fspath(filename)
    if os.path.abspath(filename) == os.path.abspath(path):
        return True
    return (os.path.dirname(os.path.abspath(filename)) == os.path.dirname(os.path.abspath(path))
            and os.path.basename(filename).startswith(os.path.basename(path) + "."))


#: How many writer calls of this process stalled and were abandoned (their threads still wait):
#: a process with one ends through ``os._exit`` once its message is out.
STALLED_WRITERS = 0


def bounded_call(call, seconds: float, path, what: str):
    """``call()`` in a thread of its own, waited for at most ``seconds``: a native writer that
    stalls (Rerun's ``save`` on a full disk never returns) becomes an :class:`OSError` naming
    ``path`` instead of a hang. The stalled thread is a daemon and ends with the process."""
    import threading

    outcome = {}

    def run():
        try:
            outcome["value"] = call()
        except BaseException as exc:  # noqa: BLE001 (handed to the waiting thread)
            outcome["error"] = exc

    import time

    worker = threading.Thread(target=run, name=f"bounded {what}", daemon=True)
    worker.start()
    start = time.monotonic()
    while worker.is_alive():
        worker.join(0.1)
        waited = time.monotonic() - start
        # a disk that refuses writes will not start taking them: give up soon, not at the limit
        if worker.is_alive() and (waited >= seconds or (waited >= DISK_GRACE_S and _refuses_writes(path))):
            global STALLED_WRITERS
            STALLED_WRITERS += 1
            raise stalled_writer_error(path, f"{what} did not return within {waited:.0f} s")
    if "error" in outcome:
        raise outcome["error"]
    return outcome.get("value")
