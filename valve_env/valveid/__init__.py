"""The valve's identification, on the generic core :mod:`valve_env.ident`: pre-processing of the
temperature channels, the valve model with its effects and errors in variables (as SDE models for the
EKF likelihood and as output-error models), the fit (``thermovalve fit``), the diagnosis (``thermovalve
diagnose``: find what the calibrated valve model gets wrong, name the physical cause, extend the model
and measure the gain; docs/reference.md, sections 3 and 4; docs/diagnosis.md) and their reports.

Public API (imported lazily, so that ``thermovalve`` starts fast):

* :func:`diagnose` (a DataFrame), :func:`diagnose_files` (CSV paths) -> :class:`Diagnosis`
  (``.cause``, ``.selected``, ``.findings``, ``.to_json()``, ``.summary()``); :class:`DiagnosisError`
* :func:`write_report` (markdown + PNG figures)
* :func:`effect_model` (the effects as SDE models for the estimator)
* :func:`jump_band` (stiction's band from the jumps of the opening), :func:`band_sampling` (that
  estimator's sampling distribution on a known opening)

The model-based bootstrap behind the named effects' sd is :func:`valve_env.valveid.bootstrap.bootstrap`.
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

_LAZY = {
    "diagnose": "valve_env.valveid.diagnose",
    "diagnose_files": "valve_env.valveid.diagnose",
    "Diagnosis": "valve_env.valveid.diagnose",
    "DiagnosisError": "valve_env.valveid.diagnose",
    "Finding": "valve_env.valveid.diagnose",
    "write_report": "valve_env.valveid.report",
    "effect_model": "valve_env.valveid.sde_effects",
    "jump_band": "valve_env.valveid.stiction",
    "band_sampling": "valve_env.valveid.stiction",
}

__all__ = sorted(_LAZY)


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'valve_env.valveid' has no attribute {name!r}")
