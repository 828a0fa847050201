"""The examples write under out/ by default, name what they wrote, and replace a file only with --force."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _run(args: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg"}
    return subprocess.run([sys.executable, str(ROOT / "examples" / "hysteresis_loop.py"), *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=120)


def test_hysteresis_loop_writes_under_out_and_names_the_file(tmp_path: Path) -> None:
    first = _run([], tmp_path)
    assert first.returncode == 0, first.stderr
    fig = tmp_path / "out" / "hysteresis_loop.png"
    assert fig.is_file() and fig.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "wrote out/hysteresis_loop.png" in first.stdout
    assert [p.name for p in tmp_path.iterdir()] == ["out"]  # nothing beside it in the working directory
    before = fig.read_bytes()
    again = _run([], tmp_path)
    assert again.returncode == 2 and "use --force" in again.stderr and len(again.stderr.strip().splitlines()) == 1
    assert fig.read_bytes() == before
    forced = _run(["--force"], tmp_path)
    assert forced.returncode == 0 and "wrote out/hysteresis_loop.png" in forced.stdout
