"""The core installs as a wheel and works outside the repository (docs/architecture.md,
"Package data").

The test copies the sources that git tracks (pyproject.toml, README.md, LICENSE, valve_env/, agents/) to
a temporary directory, builds the wheel there, installs it with the core's dependencies (no ``rl``
extra: no torch, no stable-baselines3) into a fresh virtualenv pinned by constraints.txt, and from a
temporary working directory that is not the repository runs ``thermovalve demo``, ``evaluate`` (with a
packaged scenario), ``experiment``, ``fit`` and ``diagnose`` on the generated run. It also checks that
the installed package, not the repository, is what runs; that the packaged configs load (the PI's gains,
the scenario); and that a trained agent's name says which extra to install.

Cost: 113-130 s on the project's 2-core machine shared with other work (build 3 s, the install 15-17 s
from pip's cache with ``--no-compile``, the commands with an empty numba cache the rest: demo 19-28 s,
diagnose 28-29 s, fit 18-23 s): over the default suite's budget of about 2 minutes a test, so it is marked
``slow`` and runs with ``make test-slow`` (or ``pytest -m slow tests/test_wheel.py``).
"""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SOURCES = ("pyproject.toml", "README.md", "LICENSE", "valve_env", "agents")
EFFECT_NAMES = {"none", "sensor_lag", "medium_temperature", "stiction", "setpoint_drift"}


def _tracked_sources(dest: Path) -> None:
    """Copy what a clean checkout holds of SOURCES (git's list; the tree without caches outside git)."""
    try:
        listed = subprocess.run(["git", "ls-files", "-z", *SOURCES], cwd=ROOT, check=True, capture_output=True,
                                text=True).stdout.split("\0")
    except (OSError, subprocess.CalledProcessError):
        listed = []
    files = [f for f in listed if f and (ROOT / f).is_file()]
    if files:
        for f in files:
            (dest / f).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / f, dest / f)
        return
    for name in SOURCES:
        src = ROOT / name
        if src.is_dir():
            shutil.copytree(src, dest / name, ignore=shutil.ignore_patterns("__pycache__", "*.py[co]", "*.nb[ic]"))
        else:
            shutil.copy2(src, dest / name)


def _setuptools_builds_here() -> bool:
    try:
        import setuptools
    except ImportError:
        return False
    return int(setuptools.__version__.split(".")[0]) >= 77  # pyproject's build-system requirement


def _run(argv: list[str], cwd: Path, env: dict[str, str], timeout: float = 600) -> subprocess.CompletedProcess[str]:
    proc = subprocess.run(argv, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert proc.returncode == 0, f"{' '.join(map(str, argv))} exited {proc.returncode}:\n{proc.stdout}\n{proc.stderr}"
    return proc


@pytest.mark.slow
def test_the_wheel_installs_and_runs_outside_the_repository(tmp_path: Path) -> None:
    times: dict[str, float] = {}
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
    env.update(THERMOVALVE_NO_PROGRESS="1", MPLBACKEND="Agg")

    # build the wheel from a copy of the tracked sources (nothing is written into the repository)
    t0 = time.perf_counter()
    src, dist = tmp_path / "src", tmp_path / "dist"
    src.mkdir()
    _tracked_sources(src)
    build = [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(dist), str(src)]
    if _setuptools_builds_here():
        build.insert(5, "--no-build-isolation")
    _run(build, tmp_path, env)
    (wheel,) = dist.glob("thermovalve-*.whl")
    times["build"] = time.perf_counter() - t0

    # a fresh virtualenv outside the repository, the core's dependencies at the tested versions
    t0 = time.perf_counter()
    venv = tmp_path / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", str(venv)], tmp_path, env)
    python = venv / "bin" / "python"
    _run([sys.executable, "-m", "pip", "--python", str(python), "install", "-q", "--no-compile",
          "-c", str(ROOT / "constraints.txt"), str(wheel)], tmp_path, env)
    times["install"] = time.perf_counter() - t0

    work = tmp_path / "work"
    work.mkdir()
    assert ROOT not in work.parents and not (work / "configs").exists()
    code = "import sys, valve_env, agents; print(valve_env.__file__, agents.__file__, *sys.path, sep='\\n')"
    lines = _run([str(python), "-c", code], work, env).stdout.splitlines()
    assert all(Path(p).resolve().is_relative_to(venv.resolve()) for p in lines[:2]), lines[:2]
    assert not [p for p in lines[2:] if p and Path(p).resolve().is_relative_to(ROOT)], lines[2:]

    thermovalve = str(venv / "bin" / "thermovalve")

    def cli(*args: str) -> subprocess.CompletedProcess[str]:
        t = time.perf_counter()
        proc = _run([thermovalve, *args], work, env)
        times[args[0]] = time.perf_counter() - t
        return proc

    helptext = cli("--help").stdout
    for command in ("demo", "evaluate", "experiment", "fit", "diagnose", "train"):  # train: the agents plug-in
        assert f"    {command} " in helptext, command

    cli("demo", "--episodes", "1", "--out", "demo")
    demo = json.loads((work / "demo" / "results.json").read_text())
    assert set(demo["results"]) == {"self_acting", "pi", "pi_compensated"}
    assert (work / "demo" / "table.md").is_file() and (work / "demo" / "trajectories.png").is_file()

    # the README's scenario path, from a directory without configs/: the packaged file
    cli("evaluate", "--controllers", "self_acting,pi", "--episodes", "1", "--config",
        "configs/scenarios/cold_supply.yaml", "--env-kwargs", "horizon_h=2", "--json", "eval.json")
    evaluation = json.loads((work / "eval.json").read_text())
    assert evaluation["env"] == "ThermoValve-v0" and list(evaluation["results"]) == ["self_acting", "pi"]
    assert math.isfinite(evaluation["results"]["pi"]["kpis"]["rmse_K"]["mean"])

    cli("experiment", "--hours", "2.5", "--seed", "1", "--out", "run.csv")
    cli("fit", "run.csv", "--json", "fit.json")
    fit = json.loads((work / "fit.json").read_text())
    assert set(fit["params"]) == {"sigma", "F_hmax", "p_bset"} and fit["n"] > 500
    assert abs(fit["params"]["sigma"] - 6.41) < 3 * max(fit["std"]["sigma"], 0.3)  # the paper's valve generated it
    cli("diagnose", "run.csv", "--json", "diag.json")
    diagnosis = json.loads((work / "diag.json").read_text())
    assert diagnosis["cause"] in EFFECT_NAMES and diagnosis["findings"]

    # without the rl extra a trained agent's name says which extra to install, in one line
    proc = subprocess.run([thermovalve, "evaluate", "--controllers", "ppo", "--episodes", "1", "--json", "p.json"],
                          cwd=work, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc.stderr
    assert "'ppo'" in proc.stderr and "pip install 'thermovalve[rl]'" in proc.stderr, proc.stderr
    assert not (work / "p.json").exists()

    print("wheel test, s: " + ", ".join(f"{k} {v:.1f}" for k, v in times.items()))
