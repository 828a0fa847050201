"""A script of ``benchmarks/`` loaded by path: ``env_loop_study``, which ``benchmarks/loop_drift_study.py``
imports by path too, stays a script there until the loop diagnosis moves onto the identification core. The
research harnesses are modules of ``studies/`` and the tests import them (``import studies.NAME``)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

ROOT = Path(__file__).resolve().parents[2]


def load_study(name: str) -> ModuleType:
    """``benchmarks/<name>.py`` as module ``name`` (registered, so its process pool can pickle it)."""
    spec = importlib.util.spec_from_file_location(name, ROOT / "benchmarks" / f"{name}.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod
