"""``thermovalve loop-diagnose``: the JSON of docs/reference.md s. 10, the report, the output policy, bad input."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from valve_env.cli import main
from valve_env.loops.diagnose import CAUSES

DATA = Path(__file__).parents[1] / "data" / "plant_loops"
STICKY = DATA / "2411FIC20102_1008_1552.txt"


def test_diagnose_real_sticky_loop_with_report(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / STICKY.name
    shutil.copy(STICKY, src)
    before = src.read_bytes()
    out = tmp_path / "out.json"
    rep = tmp_path / "rep"
    assert main(["loop-diagnose", str(src), "--json", str(out), "--report", str(rep)]) == 0
    res = json.loads(out.read_text())
    assert res["cause"] in CAUSES
    assert 0.0 <= res["detection"]["probability"] <= 1.0
    for name in ("report.md", "phase.png", "simulation.png", "residuals.png", "profile.png"):
        assert (rep / name).stat().st_size > 0
    text = (rep / "report.md").read_text()
    assert "Ljung-Box" in text and "{" not in text  # no raw dict in the report
    assert src.read_bytes() == before


def test_quantify_gives_one_story(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """--quantify fits the band; the one model name (band, sd and jump) is the same in stdout, the JSON, the report's
    headline and its table."""
    out, rep = tmp_path / "out.json", tmp_path / "rep"
    assert main(["loop-diagnose", str(STICKY), "--json", str(out), "--report", str(rep), "--quantify"]) == 0
    res = json.loads(out.read_text())
    label = res["stiction"]["label"]
    assert f"{res['stiction']['band_pct']:.3g}" in label and f"{res['stiction']['jump_pct']:.3g}" in label
    assert [f["candidate"] for f in res["findings"]] == ["linear", "stiction"]
    text = (rep / "report.md").read_text()
    headline = next(line for line in text.splitlines() if line.startswith("**Cause"))
    assert label in headline and f"| model | {label} |" in text
    # the headline reads the detection as the rule that decided it (the default: Horch's phase), not the learned
    # rule's probability beside it
    phase = res["detection"]["detectors"]["horch"]["statistic"]
    verdict = "stiction" if res["detection"]["stiction"] else "no stiction"
    assert f"(detection by Horch's test: OP-PV phase {phase:.0f} deg: {verdict})" in headline
    assert "probability" not in headline
    # a band the detection did not ask for says so beside it, in the headline and on stdout
    out = capsys.readouterr().out
    assert label in out
    on_request = "(fitted on request; stiction not detected)"
    assert res["stiction"]["detected"] is False  # this record: Horch's test leaves it undetermined
    assert f"{label} {on_request}" in headline and f"{label} {on_request}" in out
    # the band's table names the valve's input and the halves' bands behind the sd (docs/loops.md, "Band uncertainty")
    halves = res["stiction"]["halves_band_pct"]
    assert f"| band read on the record's first and second half, % | {halves[0]:.3g}, {halves[1]:.3g} |" in text
    assert "controller's output jitter within a sample driving the valve" in text


def test_a_long_record_is_fitted_on_its_last_part_with_a_note(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    """A record longer than the fits read (:data:`valve_env.loops.diagnose.MAX_FIT_SAMPLES`, here cut to 500 samples):
    the detection reads the whole record, the band and the linear model its last part, and a note says so; the
    command reports its steps on stderr as it goes (a long record is not silent)."""
    import valve_env.loops.diagnose as dg
    from valve_env.loops.detect import DEFAULT_RULE, detect
    from valve_env.loops.io import read_loop
    from valve_env.outputs import json_text

    monkeypatch.setattr(dg, "MAX_FIT_SAMPLES", 500)
    out, rep = tmp_path / "out.json", tmp_path / "rep"
    assert main(["loop-diagnose", str(STICKY), "--json", str(out), "--report", str(rep), "--quantify"]) == 0
    res = json.loads(out.read_text())
    n = read_loop(STICKY).n
    assert res["loop"]["n_samples"] == n > 500
    assert res["notes"][-1].startswith(f"the grey-box fits (the band, the linear model) read the record's last 500 "
                                       f"samples ({500 * 10 / 3600:.3g} of {n * 10 / 3600:.3g} h)")
    assert math.isfinite(res["stiction"]["band_pct"]) and res["stiction"]["std_pct"] > 0
    loop = read_loop(STICKY)
    part, note = dg.fitted_part(loop)
    assert part.n == 500 and part.time_s[0] == 0.0 and np.array_equal(part.op, loop.op[-500:]) and note
    whole, none = dg.fitted_part(loop, loop.n)
    assert whole is loop and none is None
    # the detection is the whole record's
    assert json.loads(json_text(detect(loop, DEFAULT_RULE))) == res["detection"]
    assert [ln.split(" (")[0] for ln in capsys.readouterr().err.splitlines()] == [
        "loop: 1/4 detection", "loop: 2/4 linear model", "loop: 3/4 band", "loop: 4/4 band on the halves"]


def test_short_record_is_insufficient_data(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A well-formed record too short to decide gets the cause insufficient_data with its reason, exit 0."""
    lines = ["time_s,sp,pv,op"] + [f"{10 * k},50,{50 + np.sin(k / 5):.5f},{40 + np.cos(k / 5):.5f}" for k in range(126)]
    src = tmp_path / "short.csv"
    src.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out.json"
    assert main(["loop-diagnose", str(src), "--json", str(out), "--report", str(tmp_path / "rep")]) == 0
    res = json.loads(out.read_text())
    assert res["cause"] == "insufficient_data" and "126 samples" in res["reason"] and res["findings"] == []
    assert "insufficient_data" in capsys.readouterr().out
    assert "126 samples" in (tmp_path / "rep" / "report.md").read_text()


@pytest.mark.parametrize(("column", "values", "needle"), [
    ("pv", np.full(300, 3.503246e-44), "PV holds 3.50325e-44 throughout while OP moves from 35 to 45 %"),
    ("op", np.full(300, 42.0), "OP holds 42 % throughout"),
])
def test_still_channel_is_insufficient_data(tmp_path: Path, column: str, values: np.ndarray, needle: str) -> None:
    """A historian export whose PV holds one (fill) value while OP moves, or whose OP never moves, is well formed
    and cannot decide: insufficient_data with the reason in the JSON and the report, exit 0, not a refusal."""
    k = np.arange(300)
    cols = {"time_s": 10.0 * k, "sp": np.full(300, 50.0), "pv": 50 + np.sin(k / 30), "op": 40 + 5 * np.cos(k / 30)}
    cols[column] = values
    src = tmp_path / "still.csv"
    src.write_text("time_s,sp,pv,op\n" + "".join(
        ",".join(f"{cols[c][i]:.7g}" for c in ("time_s", "sp", "pv", "op")) + "\n" for i in range(300)))
    out = tmp_path / "out.json"
    assert main(["loop-diagnose", str(src), "--json", str(out), "--report", str(tmp_path / "rep")]) == 0
    res = json.loads(out.read_text())
    assert res["cause"] == "insufficient_data" and needle in res["reason"] and res["findings"] == []
    assert needle in (tmp_path / "rep" / "report.md").read_text()


def test_op_in_engineering_units_noted(tmp_path: Path) -> None:
    """An OP in engineering units is scaled by its observed range, with a note in the JSON and the report."""
    from valve_env.loops.sim import simulate_loop

    loop, _ = simulate_loop("pressure", S=0.0, seed=3, hours=0.7)
    loop.op = 380.0 + 0.06 * loop.op  # 380-386 "engineering units"
    src = tmp_path / "loop.csv"
    src.write_text(loop.to_csv_text())
    out, rep = tmp_path / "out.json", tmp_path / "rep"
    assert main(["loop-diagnose", str(src), "--json", str(out), "--report", str(rep)]) == 0
    res = json.loads(out.read_text())
    assert res["loop"]["op_scaled_from"][0] > 380.0 and res["loop"]["op_range_pct"] == pytest.approx([0.0, 100.0])
    assert any("scaled by its observed range" in n for n in res["notes"])
    assert "scaled by its observed range" in (rep / "report.md").read_text()


def test_existing_output_needs_force(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from valve_env.loops.sim import simulate_loop

    loop, _ = simulate_loop("pressure", S=0.0, seed=3, hours=0.7)
    src = tmp_path / "loop.csv"
    src.write_text(loop.to_csv_text())
    out = tmp_path / "out.json"
    out.write_text("old")
    assert main(["loop-diagnose", str(src), "--json", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("thermovalve: error:") and "--force" in err[0]
    assert out.read_text() == "old"
    assert main(["loop-diagnose", str(src), "--json", str(out), "--force"]) == 0
    assert json.loads(out.read_text())["loop"]["n_samples"] == loop.n


def test_output_over_input_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / "loop.txt"
    shutil.copy(STICKY, src)
    before = src.read_bytes()
    assert main(["loop-diagnose", str(src), "--json", str(src), "--force"]) == 2
    assert "input" in capsys.readouterr().err
    assert src.read_bytes() == before


def test_bad_csv_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    p = tmp_path / "bad.csv"
    t = np.arange(300) * 10.0
    lines = ["time_s,sp,pv,op"] + [f"{v},1,{np.sin(v)},{'inf' if i == 5 else np.cos(v)}" for i, v in enumerate(t)]
    p.write_text("\n".join(lines))
    out = tmp_path / "o.json"
    assert main(["loop-diagnose", str(p), "--json", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "column op has 1 NaN/infinite" in err[0]
    assert not out.exists()


def test_the_headline_reads_the_rule_that_decided() -> None:
    """``report.decision``: the learned rule's probability and threshold where it decided, Horch's phase where
    Horch's test did."""
    from valve_env.loops.report import decision

    det = {"stiction": True, "probability": 0.81, "threshold": 0.68, "rule": {"name": "learned"},
           "detectors": {"horch": {"statistic": 47.0}}}
    assert decision(det) == "the learned rule: probability of stiction 0.81, threshold 0.68: stiction"
    det["rule"] = {"name": "horch"}
    det["stiction"] = False
    assert decision(det) == "Horch's test: OP-PV phase 47 deg: no stiction"
