"""Both readers under random edits of a valid file, the way files get damaged or hand-edited: a line
dropped, repeated, moved or cut short, a character inserted or deleted, a cell replaced by a marker, a
field deleted or added, a BOM, CRLF line ends, the file cut off. Whatever the edit, the reader either
reads the file or refuses it with its own error in one line; never another exception (which the CLI
would print as a bare ``TypeError: ...`` or ``IndexError: ...`` line that names no row or column), and
the file is left as it was. docs/reference.md, section 2 (measured runs) and docs/loops.md, "Input
formats" (loop records).

Hypothesis draws the edits (``derandomize``: the same cases on every run)."""

from __future__ import annotations

import functools
import hashlib
import shutil
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

DATA = Path(__file__).resolve().parents[1] / "data" / "plant_loops"
#: characters a damaged or hand-edited file gains: separators, quotes, signs, exponent letters, a
#: NUL, a no-break space, a BOM, a degree sign
CHARS = list(",;\t\"' -eE.:/09aZ#\r\x00\u00a0\ufeff\u00b0")
#: what a cell may be replaced by: the markers of missing values, numbers out of range or in another
#: convention, stray text
CELLS = ["", "nan", "NaN", "-", "1e400", "-0", "inf", "1,5", "x", "  ", '"', "0x10", "1_000", "+", "."]

edit = st.tuples(st.integers(0, 11), st.floats(0, 1, exclude_max=True), st.floats(0, 1, exclude_max=True),
                 st.integers(0, 4), st.sampled_from(CHARS), st.sampled_from(CELLS))


def mutate(text: str, edits: list[tuple[int, float, float, int, str, str]]) -> str:
    """``text`` with ``edits`` applied in turn: (kind, which line, where in it, a length, a character, a cell)."""
    lines = text.split("\n")
    sep = "\t" if "\t" in lines[0] else ","
    for kind, at, pos, length, char, cell in edits:
        i = int(at * len(lines))
        line = lines[i]
        j = int(pos * (len(line) + 1))
        if kind == 0 and len(lines) > 3:
            del lines[i]
        elif kind == 1:
            lines.insert(i, line)
        elif kind == 2:
            lines[i] = line[:j] + line[j + length + 1:]
        elif kind == 3:
            lines[i] = line[:j] + char + line[j:]
        elif kind == 4:
            k = int(pos * len(lines))
            lines[i], lines[k] = lines[k], lines[i]
        elif kind == 5:
            lines = lines[:i + 1]
        elif kind == 6:
            lines[i] = ""
        elif kind in (7, 8):
            cells = line.split(sep)
            c = int(pos * len(cells))
            if kind == 7:
                cells[c] = cell
            elif len(cells) > 1:
                del cells[c]
            lines[i] = sep.join(cells)
        elif kind == 9:
            lines[i] = line + sep * (length + 1)
        elif kind == 10:
            lines[0] = "\ufeff" + lines[0]
        else:
            return "\r\n".join(lines)
    return "\n".join(lines)


@functools.cache
def run_text() -> str:
    from valve_env.experiment import simulate_experiment

    df = simulate_experiment(seed=3, duration_h=2.0, dt_s=10.0)
    return str(df[[c for c in df.columns if not c.startswith("true_")]].to_csv(index=False, float_format="%.9g"))


def _read_or_refuse(read, refusal: type[Exception], p: Path) -> None:
    before = hashlib.sha256(p.read_bytes()).hexdigest()
    try:
        read(p)
    except refusal as exc:
        assert "\n" not in str(exc).strip(), f"a refusal of more than one line: {exc}"
    assert hashlib.sha256(p.read_bytes()).hexdigest() == before, "the input file was changed"


@settings(max_examples=60, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(edits=st.lists(edit, min_size=1, max_size=3))
def test_an_edited_measured_run_is_read_or_refused_in_one_line(edits: list, tmp_path: Path) -> None:
    from valve_env.valveid.diagnose import DiagnosisError, read_run

    p = tmp_path / "run.csv"
    p.write_text(mutate(run_text(), edits), encoding="utf-8")
    _read_or_refuse(read_run, DiagnosisError, p)


@pytest.mark.parametrize("name", ["2411FIC20102_1008_1552.txt", "2111LIC31102B_0826_0009.txt"])
@settings(max_examples=80, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(edits=st.lists(edit, min_size=1, max_size=3))
def test_an_edited_historian_export_is_read_or_refused_in_one_line(name: str, edits: list, tmp_path: Path) -> None:
    from valve_env.loops.io import LoopDataError, read_loop

    p = tmp_path / name
    p.write_text(mutate((DATA / name).read_text(encoding="utf-8"), edits), encoding="utf-8")
    _read_or_refuse(read_loop, LoopDataError, p)


def test_the_edits_do_edit() -> None:
    """The mutation is not a no-op: each kind of edit changes a file, and a cut changes its length."""
    text = "a,b,c\n1,2,3\n4,5,6\n7,8,9"
    changed = {k for k in range(12) if mutate(text, [(k, 0.5, 0.5, 1, "#", "x")]) != text}
    assert changed >= set(range(12)) - {4}  # a swap may swap a line with itself
    assert len(mutate(text, [(5, 0.0, 0.0, 0, "#", "")])) < len(text)


def test_a_reader_that_raises_another_error_fails_the_check(tmp_path: Path) -> None:
    """The check itself: an exception other than the reader's refusal is not taken for one."""
    p = tmp_path / "x.csv"
    shutil.copy(DATA / "2111LIC31102B_0826_0009.txt", p)

    def broken(_: Path) -> None:
        raise TypeError("unsupported operand")

    with pytest.raises(TypeError):
        _read_or_refuse(broken, KeyError, p)
