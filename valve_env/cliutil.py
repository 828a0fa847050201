"""What every ``thermovalve`` command module uses (:mod:`valve_env.cli` runs them): the exit codes and the
one-line error form, :class:`UsageError` for bad input found by a command's own checks, argument checks
(:func:`check_range`, :func:`int_list`), the ``--force`` option (:func:`add_force`) and the progress shown on
stderr (:func:`progress_bar`). It imports nothing of the commands: they import it, and the dispatcher imports them.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
from collections.abc import Callable, Iterator
from typing import Any

EXIT_OK = 0
EXIT_ERROR = 1
EXIT_BAD_INPUT = 2
PREFIX = "thermovalve: error: "



class UsageError(ValueError):
    """Bad input found by a command's own argument checks: one line, exit status 2."""


def one_line(text: object) -> str:
    """``text`` on one line (whitespace runs collapsed)."""
    return " ".join(str(text).split())


def error_message(exc: BaseException) -> str:
    """The one-line message of ``exc`` (its type's name when it has none)."""
    msg = one_line(exc)
    if isinstance(exc, KeyError) and exc.args:
        msg = one_line(exc.args[0])
    if isinstance(exc, OSError) and exc.strerror:
        msg = f"{exc.filename + ': ' if exc.filename else ''}{exc.strerror}"
    return msg or type(exc).__name__


def fail(msg: object, code: int = EXIT_BAD_INPUT) -> int:
    """Print ``thermovalve: error: <msg>`` (one line) on stderr; returns ``code``."""
    print(PREFIX + one_line(msg), file=sys.stderr, flush=True)
    return code


# --------------------------------------------------------------------------- argument checks
def check_range(name: str, value: float, lo: float | None = None, hi: float | None = None,
                lo_open: bool = False, hi_open: bool = False) -> float:
    """Raise :class:`UsageError` naming ``name`` unless ``value`` is finite and within the bounds."""
    import math

    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise UsageError(f"{name} must be a finite number, got {value!r}")
    if lo is not None and (value <= lo if lo_open else value < lo):
        raise UsageError(f"{name} must be {'>' if lo_open else '>='} {lo:g}, got {value:g}")
    if hi is not None and (value >= hi if hi_open else value > hi):
        raise UsageError(f"{name} must be {'<' if hi_open else '<='} {hi:g}, got {value:g}")
    return value


def int_list(text: str) -> list[int]:
    """Integers from a comma list with ranges, ``"0-4,10,12-13"`` -> [0, 1, 2, 3, 4, 10, 12, 13] (seeds on
    the command line); a malformed part raises ValueError."""
    out: list[int] = []
    for part in text.split(","):
        try:
            if "-" in part.strip()[1:]:
                a, b = part.split("-", 1)
                lo, hi = int(a), int(b)
                if hi < lo:
                    raise ValueError
                out += list(range(lo, hi + 1))
            elif part.strip():
                out.append(int(part))
        except ValueError:
            raise UsageError(f"bad integer list {text!r}: {part.strip()!r} is not an integer or a range a-b with "
                             "a <= b (e.g. 0-4,10)") from None
    return out


def add_force(p: argparse.ArgumentParser) -> None:
    """The ``--force`` option every writing command has."""
    p.add_argument("--force", action="store_true", help="replace existing output files (never an input)")


class _StageLines:
    """Progress where stderr is not a terminal (a log, a pipe, CI): one line per finished stage,
    ``diagnose: 3/12 sensor_lag (14 s)``, so a long command is never silent."""

    def __init__(self, total: int, desc: str) -> None:
        import time

        self.total, self.desc, self.n, self.post, self.t0 = total, desc, 0, "", time.perf_counter()

    def set_postfix_str(self, s: str) -> None:
        self.post = s

    def update(self, n: int = 1) -> None:
        import time

        self.n += n
        what = f" {self.post}" if self.post else ""
        print(f"{self.desc}: {self.n}/{self.total}{what} ({time.perf_counter() - self.t0:.0f} s)", file=sys.stderr,
              flush=True)

    def close(self) -> None:
        pass


def progress_bar(total: int, desc: str = "", unit: str = "it") -> Any:
    """Progress on stderr (``.update(n)``, ``.set_postfix_str(s)``, ``.close()``): a tqdm bar on a
    terminal, one line per finished stage otherwise; off when THERMOVALVE_NO_PROGRESS is set."""
    if os.environ.get("THERMOVALVE_NO_PROGRESS"):
        from tqdm import tqdm as plain  # not tqdm.auto: in a notebook without ipywidgets it warns on import

        return plain(total=total, disable=True)
    if not sys.stderr.isatty():
        return _StageLines(total, desc)
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, leave=False)


@contextlib.contextmanager
def stage_progress(total: int, desc: str, unit: str = "step") -> Iterator[Callable[[str], None]]:
    """A :func:`progress_bar` of ``total`` stages as the ``progress`` callback a long computation takes:
    ``tick(msg)`` names the stage just finished and counts it; the bar closes on leaving the block, full when the
    block succeeds (``total`` counts the stages a run may need: a run that needs fewer, a diagnosis that names no
    effect and so bootstraps none, ends there too)."""
    bar = progress_bar(total, desc=desc, unit=unit)

    def tick(msg: str) -> None:
        bar.set_postfix_str(msg)
        bar.update(1)

    try:
        yield tick
        if bar.n < total:
            bar.set_postfix_str("done")
            bar.update(total - bar.n)
    finally:
        bar.close()


__all__ = ["EXIT_OK", "EXIT_ERROR", "EXIT_BAD_INPUT", "PREFIX", "UsageError", "one_line", "error_message", "fail",
           "check_range", "int_list", "add_force", "progress_bar",
           "stage_progress"]
