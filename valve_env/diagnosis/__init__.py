"""Diagnosis: find what the calibrated valve simulation gets wrong, name the physical cause,
extend the model and measure the gain (docs/reference.md, sections 3 and 4; docs/diagnosis.md).

Public API (imported lazily, so that ``thermovalve`` starts fast):

* :func:`diagnose` (a DataFrame), :func:`diagnose_files` (CSV paths) -> :class:`Diagnosis`
  (``.cause``, ``.selected``, ``.findings``, ``.to_json()``, ``.summary()``); :class:`DiagnosisError`
* :func:`write_report` (markdown + PNG figures)
* :data:`EFFECTS` (the effect library), :func:`effect_model` (the effects as SDE models for the estimator)
* :func:`run_bench` (speed of a 24 h diagnosis)
* :func:`bootstrap` (the model-based bootstrap behind the named effects' sd), :func:`jump_band`
  (stiction's band from the jumps of the opening), :func:`band_sampling` (that estimator's sampling
  distribution on a known opening)
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

_LAZY = {
    "diagnose": "valve_env.diagnosis.diagnose",
    "diagnose_files": "valve_env.diagnosis.diagnose",
    "Diagnosis": "valve_env.diagnosis.diagnose",
    "DiagnosisError": "valve_env.diagnosis.diagnose",
    "Finding": "valve_env.diagnosis.diagnose",
    "write_report": "valve_env.diagnosis.report",
    "EFFECTS": "valve_env.diagnosis.effects",
    "effect_model": "valve_env.diagnosis.sde_effects",
    "run_bench": "valve_env.diagnosis.bench",
    "bootstrap": "valve_env.estimation.bootstrap",
    "jump_band": "valve_env.diagnosis.stiction",
    "band_sampling": "valve_env.diagnosis.stiction",
}

__all__ = sorted(_LAZY)


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'valve_env.diagnosis' has no attribute {name!r}")
