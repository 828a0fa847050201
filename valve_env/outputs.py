"""One output policy for every command and every file the project writes.

1. **Never over an input.** An output that is the same file as an input (by
   path, through a symlink or a hard link) is refused.
2. **Never replace an existing output without ``force``.**
3. **Atomic writes.** Every file is written to a temporary name in its own
   directory and renamed into place (``os.replace``), so an interrupted or
   failed run leaves the previous result intact and no partial file.
4. **All or nothing.** A command that writes several files stages them in an
   :class:`OutputSet` and commits them together at the end: a run that fails
   half-way leaves none of its outputs behind.

Usage::

    outs = OutputSet(inputs=[run_csv], force=args.force)
    json_path = outs.add(args.json_out)          # checks 1 and 2 at once, before any work
    ...                                          # the long computation
    outs.write_text(json_path, text)             # staged under a temporary name
    outs.commit()                                # renamed into place, together
    print(outs.summary())                        # "wrote out.json, out.md"

Every refusal raises :class:`OutputError`, whose message is one line naming the
file and the problem; the command-line layer prints it and exits with status 2.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import tempfile
import threading
import weakref
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

PathLike = str | os.PathLike[str]

#: where commands write by default (never into tracked files)
DEFAULT_OUT_DIR = Path("out")


class OutputError(ValueError):
    """An output that must not be written; the message is one line naming the problem."""


def _same_file(a: Path, b: Path) -> bool:
    try:
        if a.resolve() == b.resolve():
            return True
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def under_default_out(path: PathLike) -> bool:
    """Whether ``path`` is :data:`DEFAULT_OUT_DIR` (``out/`` of the working directory) or below it: there a
    missing directory is created for an output (``--json out/eval.json`` works in a fresh checkout);
    elsewhere a missing directory is refused (a typo must not scatter results)."""
    root = Path(os.path.abspath(DEFAULT_OUT_DIR))
    q = Path(os.path.abspath(path))
    return q == root or root in q.parents


def check_output(path: PathLike, inputs: Iterable[PathLike | None] = (), force: bool = False,
                 what: str = "output") -> Path:
    """Check that ``path`` may be written: not an input, not a directory, its directory exists (or lies
    under ``out/``: see :func:`under_default_out`), and it does not exist unless ``force``. Returns it as a
    Path; raises :class:`OutputError`."""
    p = Path(path)
    for inp in inputs:
        if inp is not None and _same_file(p, Path(inp)):
            raise OutputError(f"{what} {p} is the input {inp}; refusing to overwrite an input")
    if p.is_dir():
        raise OutputError(f"{what} {p} is a directory")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        if not under_default_out(parent):
            raise OutputError(f"cannot write {what} {p}: directory {parent} does not exist")
        # under out/ (the default output root) a missing directory is made when the file is staged
        anc = _existing_ancestor(parent)
        if not anc.is_dir():
            raise OutputError(f"cannot write {what} {p}: {anc} is not a directory")
        parent = anc
    if not os.access(parent, os.W_OK):
        raise OutputError(f"cannot write {what} {p}: directory {parent} is not writable")
    if (p.exists() or p.is_symlink()) and not force:
        raise OutputError(f"{what} {p} exists; use --force to replace it")
    return p


def check_output_dir(path: PathLike, inputs: Iterable[PathLike | None] = (), force: bool = False,
                     what: str = "output directory") -> Path:
    """Check a directory that a command fills: not an input, not a file; when it exists and holds
    files, ``force`` is needed. It is created (with its parents) when missing."""
    p = Path(path)
    for inp in inputs:
        if inp is not None and _same_file(p, Path(inp)):
            raise OutputError(f"{what} {p} is the input {inp}; refusing to overwrite an input")
    if p.exists() and not p.is_dir():
        raise OutputError(f"{what} {p} exists and is not a directory")
    if p.is_dir() and not force and any(q.is_file() or q.is_symlink() for q in p.rglob("*")):
        raise OutputError(f"{what} {p} exists and is not empty; use --force to replace its files")
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"cannot create {what} {p}: {exc.strerror or exc}") from exc
    return p


def _umask() -> int:
    """The process's umask (read by setting and restoring it: POSIX has no read-only call)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def _signals_held() -> Iterator[None]:
    """SIGINT and SIGTERM held back for a step that must not be cut in half (a temporary made and
    recorded where the clean-up will find it; the commit's renames); a signal that came meanwhile is
    delivered at the end. The commands turn both signals into exceptions (valve_env/cli.py), which Python
    raises between any two statements: without this, one arriving just after a temporary was made and
    before it was recorded left it behind. The Python-level handlers are swapped for one that only records
    the signal, rather than the main thread's signal mask: a process-directed signal reaches any thread that
    does not block it (a numerical library's worker, a progress bar's monitor), and Python then runs its
    handler in the main thread all the same (measured: a fit's commit cut between the JSON and its report)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []

    def hold(signum: int, frame: object) -> None:
        caught.append(signum)

    old: dict[int, Any] = {}
    for sig in (signal.SIGINT, signal.SIGTERM):
        if signal.getsignal(sig) is not None:  # None: a handler not installed from Python, left alone
            old[sig] = signal.signal(sig, hold)
    try:
        yield
    finally:
        for held, previous in old.items():
            signal.signal(held, previous)
        for signum in dict.fromkeys(caught):
            handler = old[signum]
            if callable(handler):
                handler(signum, None)
            elif handler == signal.SIG_DFL:
                signal.raise_signal(signum)


@contextlib.contextmanager
def _temp_beside(p: Path, on_create: Callable[[Path], object] | None = None) -> Iterator[Path]:
    """A new temporary file beside ``p`` (same directory, so a rename onto ``p`` is atomic), fsynced
    when the block succeeds and removed when it raises. ``on_create`` records it (for an
    :class:`OutputSet`'s clean-up) in the same uninterruptible step that makes it."""
    tmp_path: Path | None = None
    try:
        with _signals_held():
            fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent if str(p.parent) else ".")
            tmp_path = Path(tmp)
            if on_create is not None:
                on_create(tmp_path)
            # mkstemp makes the file 0600; an output gets the mode a plain open() would give it (0666 less
            # the umask)
            os.fchmod(fd, 0o666 & ~_umask())
            os.close(fd)
        yield tmp_path
        _fsync(tmp_path)
    except BaseException:
        if tmp_path is not None:
            with contextlib.suppress(OSError):
                tmp_path.unlink()
        raise


@contextlib.contextmanager
def atomic_path(path: PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success it is renamed onto ``path``, on
    failure removed. Use for writers that want a file name (``savefig``, ``to_csv``)."""
    p = Path(path)
    with _temp_beside(p) as tmp_path:
        yield tmp_path
    try:
        os.replace(tmp_path, p)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp_path.unlink()
        raise


@contextlib.contextmanager
def atomic_dir(path: PathLike) -> Iterator[Path]:
    """Yield a new, empty temporary directory beside ``path`` to fill (``.NAME.*.tmp``); when the block succeeds it
    takes ``path``'s place whole (a directory there before is moved aside in the same uninterruptible step and then
    removed), and when it fails or is interrupted it is removed and ``path`` stays as it was. For a writer that
    fills a directory as it goes, a training run (no check: a caller checks ``path`` first)."""
    p = Path(path)
    parent = p.parent if str(p.parent) else Path(".")
    parent.mkdir(parents=True, exist_ok=True)
    with _signals_held():
        tmp = Path(tempfile.mkdtemp(prefix=f".{p.name}.", suffix=".tmp", dir=parent))
        os.chmod(tmp, 0o777 & ~_umask())  # mkdtemp makes it 0700; a directory gets what mkdir would give it
    aside: Path | None = None
    try:
        yield tmp
        with _signals_held():
            if p.exists() or p.is_symlink():
                aside = Path(tempfile.mkdtemp(prefix=f".{p.name}.old.", suffix=".tmp", dir=parent))
                os.replace(p, aside / p.name)
            os.replace(tmp, p)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        if aside is not None and (aside / p.name).exists() and not p.exists():
            os.replace(aside / p.name, p)  # the swap failed half-way: the old directory back in its place
        raise
    finally:
        if aside is not None:
            shutil.rmtree(aside, ignore_errors=True)


def _existing_ancestor(p: Path) -> Path:
    q = p.absolute()
    while not q.exists() and q != q.parent:
        q = q.parent
    return q


def _fsync(p: Path) -> None:
    with contextlib.suppress(OSError), open(p, "rb") as fh:
        os.fsync(fh.fileno())


def atomic_write_text(path: PathLike, text: str) -> Path:
    """Write ``text`` to ``path`` atomically (no check: use :func:`check_output` first)."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return Path(path)


def atomic_write_bytes(path: PathLike, data: bytes) -> Path:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def json_safe(obj: object) -> object:
    """``obj`` for JSON: non-finite floats as null (JSON has no NaN/inf), numpy scalars and arrays
    as Python numbers and lists, tuples as lists."""
    import math

    import numpy as np

    if isinstance(obj, np.ndarray):
        return json_safe(obj.tolist())
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    return obj


def json_text(obj: object, indent: int | None = 2, default: Callable[[object], object] | None = None) -> str:
    """JSON text of ``obj`` through :func:`json_safe` (never NaN/Infinity), ending in a newline."""
    import json

    return json.dumps(json_safe(obj), indent=indent, allow_nan=False, default=default) + "\n"


class OutputSet:
    """The outputs of one command run: checked up front, staged under temporary names,
    renamed into place together by :meth:`commit`, removed by :meth:`discard` (also on
    garbage collection, so an exception never leaves a staged file behind)."""

    def __init__(self, inputs: Iterable[PathLike | None] = (), force: bool = False) -> None:
        self.inputs = [Path(p) for p in inputs if p is not None]
        self.force = force
        self._declared: list[Path] = []
        self._staged: dict[Path, Path] = {}
        self._staged_dirs: dict[Path, Path] = {}
        #: every temporary file made and not yet renamed into place or removed (what discard removes)
        self._temps: set[Path] = set()
        self.written: list[Path] = []
        _LIVE.add(self)

    def add(self, path: PathLike, what: str = "output") -> Path:
        """Declare an output; refuses an input, an existing file without force, or a path
        declared twice."""
        p = check_output(path, self.inputs, self.force, what)
        for q in self._declared:
            if _same_file(p, q):
                raise OutputError(f"{what} {p} is named twice")
        self._declared.append(p)
        return p

    def add_dir(self, path: PathLike, what: str = "output directory") -> Path:
        return check_output_dir(path, self.inputs, self.force, what)

    def add_in_dir(self, directory: PathLike, names: Iterable[str], what: str = "output") -> list[Path]:
        """Declare the files ``names`` that a writer will put into ``directory`` (which may not exist
        yet: it is created at :meth:`commit`). Checks up front, like :meth:`add`, without creating
        anything; use with :meth:`stage_dir`."""
        d = Path(directory)
        for inp in self.inputs:
            if _same_file(d, inp):
                raise OutputError(f"{what} directory {d} is the input {inp}; refusing to overwrite an input")
        if d.exists() and not d.is_dir():
            raise OutputError(f"{what} directory {d} exists and is not a directory")
        if not d.is_dir():
            anc = _existing_ancestor(d)
            if not os.access(anc, os.W_OK):
                raise OutputError(f"cannot create {what} directory {d}: {anc} is not writable")
            out = [d / n for n in names]
            for target in out:
                if any(_same_file(target, q) for q in self._declared):
                    raise OutputError(f"{what} {target} is named twice")
            self._declared += out
            return out
        out = []
        for n in names:
            target = d / n
            if target.parent.is_dir():
                out.append(self.add(target, what))
            else:  # a subdirectory made at commit
                self._declared.append(target)
                out.append(target)
        return out

    def stage_dir(self, directory: PathLike) -> Path:
        """A temporary directory (beside ``directory``) for writers that fill a directory
        (figures, reports); :meth:`commit` moves each of its files into ``directory`` (each
        rename atomic), checking every file it did not see declared as it checks :meth:`add`."""
        d = Path(directory)
        if d in self._staged_dirs:
            return self._staged_dirs[d]
        base = d if d.is_dir() else _existing_ancestor(d)
        with _signals_held():
            tmp = Path(tempfile.mkdtemp(prefix=f".{d.name or 'out'}.", suffix=".tmp", dir=base))
            self._staged_dirs[d] = tmp
        return tmp

    def stage(self, path: PathLike, writer: Callable[[Path], object]) -> Path:
        """Call ``writer(tmp_path)`` to write the file under a temporary name."""
        p = Path(path)
        if not any(_same_file(p, q) or p == q for q in self._declared):
            self.add(p)
        if not p.parent.is_dir() and under_default_out(p.parent):
            p.parent.mkdir(parents=True, exist_ok=True)
        with _temp_beside(p, on_create=self._temps.add) as tmp_path:
            writer(tmp_path)
        old = self._staged.pop(p, None)
        if old is not None:
            with contextlib.suppress(OSError):
                old.unlink()
            self._temps.discard(old)
        self._staged[p] = tmp_path
        return p

    def write_text(self, path: PathLike, text: str) -> Path:
        return self.stage(path, lambda tmp: tmp.write_text(text))

    def write_bytes(self, path: PathLike, data: bytes) -> Path:
        return self.stage(path, lambda tmp: tmp.write_bytes(data))

    def commit(self) -> list[Path]:
        """Rename every staged file into place (each rename is atomic). Every file of a staged
        directory is checked first, so a refusal leaves nothing renamed. SIGINT and SIGTERM are held
        back while the renames run: a signal then ends the run after its outputs are all in place,
        never with some of them new and the rest old (a few renames: milliseconds)."""
        with _signals_held():
            return self._commit()

    def _commit(self) -> list[Path]:
        moves: list[tuple[Path, Path]] = []
        for d, tmp_dir in self._staged_dirs.items():
            for f in sorted(q for q in tmp_dir.rglob("*") if q.is_file()):
                target = d / f.relative_to(tmp_dir)
                if not any(target == q or _same_file(target, q) for q in self._declared):
                    for inp in self.inputs:
                        if _same_file(target, inp):
                            raise OutputError(f"output {target} is the input {inp}; refusing to overwrite an input")
                    if target.exists() and not self.force:
                        raise OutputError(f"output {target} exists; use --force to replace it")
                moves.append((f, target))
        for final, tmp in list(self._staged.items()):
            self._place(tmp, final)
            self.written.append(final)
            del self._staged[final]
            self._temps.discard(tmp)
        for f, target in moves:
            target.parent.mkdir(parents=True, exist_ok=True)
            self._place(f, target)
            self.written.append(target)
        for tmp_dir in self._staged_dirs.values():
            shutil.rmtree(tmp_dir, ignore_errors=True)
        self._staged_dirs.clear()
        return self.written

    def _place(self, tmp: Path, final: Path) -> None:
        """Rename ``tmp`` onto ``final``. Without ``force`` the rename must not replace a file
        that appeared while the run was working (two runs writing one path): a hard link,
        which fails when ``final`` exists, makes that check and the placing one atomic step."""
        if self.force:
            os.replace(tmp, final)
            return
        try:
            os.link(tmp, final)
        except FileExistsError:
            raise OutputError(f"output {final} appeared while this run was working (another run?); "
                              "use --force to replace it") from None
        except OSError:  # no hard links on this file system: the check made up front stands
            os.replace(tmp, final)
            return
        with contextlib.suppress(OSError):
            tmp.unlink()

    def discard(self) -> None:
        for tmp in (*self._staged.values(), *self._temps):
            with contextlib.suppress(OSError):
                tmp.unlink()
        self._staged.clear()
        self._temps.clear()
        for tmp_dir in self._staged_dirs.values():
            shutil.rmtree(tmp_dir, ignore_errors=True)
        self._staged_dirs.clear()

    def summary(self) -> str:
        return "wrote " + ", ".join(str(p) for p in self.written) if self.written else "wrote nothing"

    def __enter__(self) -> OutputSet:
        return self

    def __exit__(self, exc_type: object, exc: object, tb: object) -> None:
        if exc_type is None:
            try:
                self.commit()
            except BaseException:  # a refusal found while committing, or SIGTERM/Ctrl-C in the middle
                self.discard()
                raise
        else:
            self.discard()

    def __del__(self) -> None:  # pragma: no cover - best effort
        with contextlib.suppress(Exception):
            self.discard()


#: every OutputSet not yet garbage-collected: :func:`discard_uncommitted` clears what they staged
_LIVE: weakref.WeakSet[OutputSet] = weakref.WeakSet()


def discard_uncommitted() -> None:
    """Remove whatever any output set has staged and not committed. The commands call it when they end
    (valve_env/cli.py, ``run_command``): a signal or an error between staging and committing (a report
    directory staged while the fit's report is drawn, say) would otherwise leave the temporaries until
    the set is garbage-collected, which an interpreter that is exiting need not do (a set caught in a
    reference cycle is not). A committed set has nothing staged, so this never removes an output."""
    for outs in list(_LIVE):
        with contextlib.suppress(Exception):
            outs.discard()


__all__ = ["OutputError", "OutputSet", "discard_uncommitted", "check_output", "check_output_dir", "atomic_path",
           "atomic_dir", "atomic_write_text", "atomic_write_bytes", "DEFAULT_OUT_DIR", "json_safe", "json_text",
           "under_default_out"]
