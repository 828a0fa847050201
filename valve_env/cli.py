"""The ``thermovalve`` command: one style for every sub-command.

Each sub-command lives beside the code it runs. A module in SUBCOMMAND_MODULES exposes
``register(subparsers)``, which adds its sub-parser(s) with ``set_defaults(func=...)``;
``func(args)`` returns the exit code (or None for 0).

Adding a sub-command (``loop-diagnose``, ``tasks``, ``benchmark``, ...):

1. write ``register(subparsers)`` in the module that does the work and add the module
   to SUBCOMMAND_MODULES, or, outside the core, to the ``thermovalve.cli`` entry points of its
   distribution (:mod:`valve_env.plugins`; import the heavy parts inside ``func``, not at module
   level: ``thermovalve --help`` imports every module listed here);
2. in ``func``, **raise** on bad input instead of printing: :class:`UsageError` (or
   :class:`~valve_env.params.ConfigError`, :class:`~valve_env.data_io.DataError`,
   :class:`~valve_env.outputs.OutputError`, any ``ValueError``) becomes one line
   ``thermovalve: error: <message>`` on stderr and exit status 2; any other exception
   becomes one line and exit status 1 (the traceback only with ``THERMOVALVE_DEBUG=1``);
   a missing optional dependency (``ImportError`` of stable_baselines3/torch/dask) names
   the extra to install; a reader of stdout that leaves (``| head``) ends the command quietly
   with status 141, an interrupt with 130;
3. write every file through one :class:`~valve_env.outputs.OutputSet`: add ``--force``
   with :func:`add_force`, ``add()`` every output before the long work, stage, commit
   (or ``with OutputSet(...) as outs:``), then ``print(outs.summary())``;
4. long steps show a progress bar: :func:`progress_bar` (tqdm on stderr; off when
   ``THERMOVALVE_NO_PROGRESS`` is set or stderr is not a terminal).

Argument-parsing errors take the same one-line form and exit status 2. Help shows each
option's default and no reStructuredText markup. SIGTERM ends a run like Ctrl-C: staged
outputs are discarded, the previous results stay intact.
"""

from __future__ import annotations

import argparse
import importlib
import os
import re
import signal
import sys
import traceback
from collections.abc import Callable, Sequence
from typing import Any, NoReturn

from valve_env.plugins import CLI_GROUP, missing_extra, plugins

SUBCOMMAND_MODULES: tuple[str, ...] = (
    "valve_env.bench",
    "valve_env.valveid.cli",
    "valve_env.evaluation.cli",
    "valve_env.loops.cli",
    "valve_env.tasks.cli",
)
"""The core's sub-command modules; plug-ins add theirs through the ``thermovalve.cli`` entry points
(:mod:`valve_env.plugins`: the RL add-on's ``agents.cli``)."""

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


def _bad_input_types() -> tuple[type[BaseException], ...]:
    from valve_env.data_io import DataError
    from valve_env.outputs import OutputError
    from valve_env.params import ConfigError

    return (UsageError, ConfigError, DataError, OutputError, ValueError, TypeError, KeyError)


def run_command(func: Callable[[argparse.Namespace], int | None], args: argparse.Namespace) -> int:
    """Run a sub-command with the shared error handling (see the module docstring). Numerical
    RuntimeWarnings of the optimisers are not shown (THERMOVALVE_DEBUG=1 shows them): bad input is
    rejected by validation, with one line, before any computation."""
    import warnings

    from valve_env.outputs import discard_uncommitted

    try:
        with warnings.catch_warnings():
            if not os.environ.get("THERMOVALVE_DEBUG"):
                warnings.simplefilter("ignore", RuntimeWarning)
            try:
                code = int(func(args) or 0)
                sys.stdout.flush()  # a reader that left shows here, not at the interpreter's exit
                return code
            finally:  # whatever a command staged and did not commit (an error, a signal) goes now
                discard_uncommitted()
    except KeyboardInterrupt:
        print("thermovalve: interrupted; no output was replaced", file=sys.stderr)
        return 130
    except _Terminated:
        print("thermovalve: terminated; no output was replaced", file=sys.stderr)
        return 143
    except BrokenPipeError:
        # the reader of stdout left (`thermovalve tasks | head`): stop quietly as Unix tools do, with the status
        # of a process ended by SIGPIPE, and keep the interpreter from reporting the flush at exit
        # (the Python documentation's recipe, "Note on SIGPIPE")
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except ImportError as exc:
        advice = missing_extra(exc)
        if os.environ.get("THERMOVALVE_DEBUG"):
            traceback.print_exc()
        if advice:
            return fail(advice, EXIT_ERROR)
        return fail(f"{type(exc).__name__}: {error_message(exc)}", EXIT_ERROR)
    except MemoryError:
        return fail("out of memory", EXIT_ERROR)
    except _bad_input_types() as exc:
        if os.environ.get("THERMOVALVE_DEBUG"):
            traceback.print_exc()
        return fail(error_message(exc), EXIT_BAD_INPUT)
    except PermissionError as exc:
        return fail(f"permission denied: {exc.filename or error_message(exc)}", EXIT_BAD_INPUT)
    except Exception as exc:  # noqa: BLE001 - never a bare traceback: one line, exit 1
        if os.environ.get("THERMOVALVE_DEBUG"):
            traceback.print_exc()
        return fail(f"{type(exc).__name__}: {error_message(exc)} (THERMOVALVE_DEBUG=1 shows the traceback)",
                    EXIT_ERROR)


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
    from tqdm.auto import tqdm

    if os.environ.get("THERMOVALVE_NO_PROGRESS"):
        return tqdm(total=total, disable=True)
    if not sys.stderr.isatty():
        return _StageLines(total, desc)
    return tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, leave=False)


# --------------------------------------------------------------------------- parser
_MARKUP = (
    (re.compile(r":[a-z]+:`~?([^`<]*?)(?:\s*<[^>]*>)?`"), r"\1"),  # :func:`x`, :class:`~a.b`
    (re.compile(r"``([^`]+)``"), r"\1"),
    (re.compile(r"(?<![\w`])`([^`]+)`_?"), r"\1"),
    (re.compile(r"\*\*([^*]+)\*\*"), r"\1"),
)


def strip_markup(text: str | None) -> str | None:
    """Help text without reStructuredText/markdown markup."""
    if text is None:
        return None
    for pat, rep in _MARKUP:
        text = pat.sub(rep, text)
    return text


class HelpFormatter(argparse.HelpFormatter):
    """Descriptions wrapped by paragraph (indented lines, e.g. examples, kept as written),
    defaults shown, no markup."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        import textwrap

        out: list[str] = []
        for para in re.split(r"\n\s*\n", text.strip("\n")):
            lines = para.splitlines()
            if any(ln.startswith((" ", "\t", "|")) for ln in lines):
                out.append("\n".join(indent + ln for ln in lines))
            else:
                out.append(textwrap.fill(" ".join(para.split()), width, initial_indent=indent,
                                         subsequent_indent=indent))
        return "\n\n".join(out)

    def _get_help_string(self, action: argparse.Action) -> str | None:
        help_text = strip_markup(action.help) or ""
        if action.default is None or action.default is False or action.default is argparse.SUPPRESS \
                or "default" in help_text:
            return help_text
        if action.option_strings or action.nargs in (argparse.OPTIONAL, argparse.ZERO_OR_MORE):
            help_text += " (default: %(default)s)"
        return help_text


class Parser(argparse.ArgumentParser):
    """argparse with the project's one-line error form and exit status 2."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs["formatter_class"] = HelpFormatter
        for key in ("description", "epilog"):
            if kwargs.get(key):
                kwargs[key] = strip_markup(kwargs[key])
        super().__init__(*args, **kwargs)

    def error(self, message: str) -> NoReturn:
        print(f"{PREFIX}{one_line(message)} (see {self.prog} --help)", file=sys.stderr)
        sys.exit(EXIT_BAD_INPUT)


class _SubParsers(argparse._SubParsersAction):  # type: ignore[type-arg]
    def add_parser(self, name: str, **kwargs: Any) -> Any:
        kwargs.pop("formatter_class", None)
        if kwargs.get("help"):
            kwargs["help"] = strip_markup(kwargs["help"])
        if kwargs.get("description"):
            kwargs["description"] = strip_markup(kwargs["description"])
        return super().add_parser(name, **kwargs)


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="thermovalve",
        description="ThermoValve: thermostatic valve environments, controllers and grey-box identification. "
                    "Bad input: one line 'thermovalve: error: ...' and exit status 2.",
    )
    parser.register("action", "parsers", _SubParsers)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    for name in SUBCOMMAND_MODULES:
        importlib.import_module(name).register(sub)
    for ep in plugins(CLI_GROUP):
        ep.load().register(sub)
    return parser


class _Terminated(BaseException):
    """SIGTERM, raised in the main thread so staged outputs are discarded."""


def _on_sigterm(signum: int, frame: object) -> None:
    raise _Terminated()


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        return fail("a command is required (see thermovalve --help)")
    previous = None
    try:
        previous = signal.signal(signal.SIGTERM, _on_sigterm)
    except ValueError:  # not the main thread
        previous = None
    try:
        return run_command(args.func, args)
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


if __name__ == "__main__":
    sys.exit(main())
