"""The ``thermovalve`` command: one style for every sub-command.

Each sub-command lives beside the code it runs and takes its helpers from :mod:`valve_env.cliutil` (which
imports none of them). A module in SUBCOMMAND_MODULES exposes
``register(subparsers)``, which adds its sub-parser(s) with ``set_defaults(func=...)``;
``func(args)`` returns the exit code (or None for 0).

Adding a sub-command (``loop-diagnose``, ``tasks``, ``benchmark``, ...):

1. write ``register(subparsers)`` in the module that does the work and add the module
   to SUBCOMMAND_MODULES, or, outside the core, to the ``thermovalve.cli`` entry points of its
   distribution (:mod:`valve_env.plugins`; import the heavy parts inside ``func``, not at module
   level: ``thermovalve --help`` imports every module listed here);
2. in ``func``, **raise** on bad input instead of printing: :class:`~valve_env.cliutil.UsageError` (or
   :class:`~valve_env.params.ConfigError`, :class:`~valve_env.data_io.DataError`,
   :class:`~valve_env.outputs.OutputError`, any ``ValueError``) becomes one line
   ``thermovalve: error: <message>`` on stderr and exit status 2; any other exception
   becomes one line and exit status 1 (the traceback only with ``THERMOVALVE_DEBUG=1``);
   a missing optional dependency (``ImportError`` of stable_baselines3/torch/dask) names
   the extra to install; a reader of stdout that leaves (``| head``) ends the command quietly
   with status 141, an interrupt with 130;
3. write every file through one :class:`~valve_env.outputs.OutputSet`: add ``--force``
   with :func:`~valve_env.cliutil.add_force`, ``add()`` every output before the long work, stage, commit
   (or ``with OutputSet(...) as outs:``), then ``print(outs.summary())``;
4. long steps show a progress bar: :func:`~valve_env.cliutil.progress_bar` (tqdm on stderr; off when
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

from valve_env.cliutil import EXIT_BAD_INPUT, EXIT_ERROR, PREFIX, UsageError, error_message, fail, one_line
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
    except (KeyboardInterrupt, _Terminated) as exc:
        return _interrupted(exc)
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
        signal_exc = _signal_behind(exc)
        if signal_exc is not None:  # a signal's exception that compiled code wrapped (a SystemError)
            return _interrupted(signal_exc)
        if os.environ.get("THERMOVALVE_DEBUG"):
            traceback.print_exc()
        return fail(f"{type(exc).__name__}: {error_message(exc)} (THERMOVALVE_DEBUG=1 shows the traceback)",
                    EXIT_ERROR)


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


def _interrupted(exc: BaseException) -> int:
    """The line and exit status of a run ended by Ctrl-C (130) or SIGTERM (143)."""
    if isinstance(exc, KeyboardInterrupt):
        print("thermovalve: interrupted; no output was replaced", file=sys.stderr)
        return 130
    print("thermovalve: terminated; no output was replaced", file=sys.stderr)
    return 143


def _signal_behind(exc: BaseException) -> BaseException | None:
    """The Ctrl-C or SIGTERM exception in ``exc``'s chain of causes: a signal handled while a compiled kernel
    returned comes back as ``SystemError: ... returned a result with an exception set``, the signal's exception its
    cause."""
    seen: set[int] = set()
    e: BaseException | None = exc
    while e is not None and id(e) not in seen:
        if isinstance(e, (KeyboardInterrupt, _Terminated)):
            return e
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return None


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
