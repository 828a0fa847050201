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
import tempfile
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

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


def check_output(path: PathLike, inputs: Iterable[PathLike | None] = (), force: bool = False,
                 what: str = "output") -> Path:
    """Check that ``path`` may be written: not an input, not a directory, its directory exists,
    and it does not exist unless ``force``. Returns it as a Path; raises :class:`OutputError`."""
    p = Path(path)
    for inp in inputs:
        if inp is not None and _same_file(p, Path(inp)):
            raise OutputError(f"{what} {p} is the input {inp}; refusing to overwrite an input")
    if p.is_dir():
        raise OutputError(f"{what} {p} is a directory")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise OutputError(f"cannot write {what} {p}: directory {parent} does not exist")
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
    if p.is_dir() and any(p.iterdir()) and not force:
        raise OutputError(f"{what} {p} exists and is not empty; use --force to replace its files")
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"cannot create {what} {p}: {exc.strerror or exc}") from exc
    return p


@contextlib.contextmanager
def atomic_path(path: PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success it is renamed onto ``path``, on
    failure removed. Use for writers that want a file name (``savefig``, ``to_csv``)."""
    p = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent if str(p.parent) else ".")
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        _fsync(tmp_path)
        os.replace(tmp_path, p)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp_path.unlink()
        raise


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


class OutputSet:
    """The outputs of one command run: checked up front, staged under temporary names,
    renamed into place together by :meth:`commit`, removed by :meth:`discard` (also on
    garbage collection, so an exception never leaves a staged file behind)."""

    def __init__(self, inputs: Iterable[PathLike | None] = (), force: bool = False) -> None:
        self.inputs = [Path(p) for p in inputs if p is not None]
        self.force = force
        self._declared: list[Path] = []
        self._staged: dict[Path, Path] = {}
        self.written: list[Path] = []

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

    def stage(self, path: PathLike, writer: Callable[[Path], object]) -> Path:
        """Call ``writer(tmp_path)`` to write the file under a temporary name."""
        p = Path(path)
        if not any(_same_file(p, q) or p == q for q in self._declared):
            self.add(p)
        fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent if str(p.parent) else ".")
        os.close(fd)
        tmp_path = Path(tmp)
        try:
            writer(tmp_path)
            _fsync(tmp_path)
        except BaseException:
            with contextlib.suppress(OSError):
                tmp_path.unlink()
            raise
        old = self._staged.pop(p, None)
        if old is not None:
            with contextlib.suppress(OSError):
                old.unlink()
        self._staged[p] = tmp_path
        return p

    def write_text(self, path: PathLike, text: str) -> Path:
        return self.stage(path, lambda tmp: tmp.write_text(text))

    def write_bytes(self, path: PathLike, data: bytes) -> Path:
        return self.stage(path, lambda tmp: tmp.write_bytes(data))

    def commit(self) -> list[Path]:
        """Rename every staged file into place (each rename is atomic)."""
        for final, tmp in list(self._staged.items()):
            os.replace(tmp, final)
            self.written.append(final)
            del self._staged[final]
        return self.written

    def discard(self) -> None:
        for tmp in self._staged.values():
            with contextlib.suppress(OSError):
                tmp.unlink()
        self._staged.clear()

    def summary(self) -> str:
        return "wrote " + ", ".join(str(p) for p in self.written) if self.written else "wrote nothing"

    def __enter__(self) -> OutputSet:
        return self

    def __exit__(self, exc_type: object, exc: object, tb: object) -> None:
        if exc_type is None:
            self.commit()
        else:
            self.discard()

    def __del__(self) -> None:  # pragma: no cover - best effort
        with contextlib.suppress(Exception):
            self.discard()


__all__ = ["OutputError", "OutputSet", "check_output", "check_output_dir", "atomic_path", "atomic_write_text",
           "atomic_write_bytes", "DEFAULT_OUT_DIR"]
