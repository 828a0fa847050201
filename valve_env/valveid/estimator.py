"""One estimator of the valve and its effects, behind which sit the project's two likelihoods.

    est = ValveEstimator(effects=("medium_temperature",), likelihood="output_error").fit(df)
    est.params_, est.std_, est.loglik_, est.n_obs_, est.n_free_, est.aic_, est.bic_, est.rms_

``data`` is a run as :func:`valve_env.data_io.load_run` reads it (a path is read with it; a
DataFrame is validated with :func:`~valve_env.data_io.validate_run`). ``effects`` are names of the
registry :mod:`valve_env.effects`. The two likelihood back-ends:

* ``"ekf"``: the continuous-discrete SDE valve model with the effects as extra states and
  parameters (:func:`valve_env.valveid.sde_effects.effect_model`), extended Kalman filter,
  :class:`~valve_env.ident.mle.MLEstimator`; the inputs are the TV-denoised temperatures.
* ``"output_error"``: the valve simulated from the IRW-RTS-smoothed temperatures, the residual an
  Ornstein-Uhlenbeck model error plus white noise (:class:`valve_env.valveid.fitting.Model`, the
  diagnosis's likelihood); standard errors the larger of the identified inverse Hessian and the HAC
  sandwich (:mod:`valve_env.ident.uncertainty`).

Both use the same parameter transforms (:mod:`valve_env.ident.sde`) and the same standard
errors (:mod:`valve_env.ident.uncertainty`). The back-end object is ``backend_`` (and, for the
output error, the diagnosis's :class:`~valve_env.valveid.fitting.FitResult` is ``result_``): the
numbers are the back-end's, unchanged.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import Any

import pandas as pd

from valve_env.data_io import load_run, validate_run
from valve_env.effects import check_effects
from valve_env.ident.mle import Estimator, MLEstimator
from valve_env.params import ValveParams
from valve_env.valveid.bootstrap import apply_bootstrap, bootstrap, withhold_conditional_std
from valve_env.valveid.data import RunData
from valve_env.valveid.fitting import Model
from valve_env.valveid.sde_effects import effect_model
from valve_env.valveid.valve_model import base_valve_model

#: the likelihood back-ends, by name
LIKELIHOODS: tuple[str, ...] = ("ekf", "output_error")


class ValveEstimator(Estimator):
    """Maximum likelihood of the valve with ``effects`` under the ``likelihood`` back-end.

    ``fixed`` holds parameters at given values; ``start`` (output error only) starts from given
    values; ``options`` go to the back-end (:class:`~valve_env.ident.mle.MLEstimator`'s
    keywords, or :meth:`valve_env.valveid.fitting.Model.fit`'s ``maxiter``/``with_std``)."""

    def __init__(self, effects: tuple[str, ...] | list[str] = (), *, likelihood: str = "ekf",
                 valve: ValveParams | None = None, fixed: Mapping[str, float] | None = None,
                 start: Mapping[str, float] | None = None, **options: Any) -> None:

        if likelihood not in LIKELIHOODS:
            raise ValueError(f"unknown likelihood {likelihood!r}; choose one of {', '.join(LIKELIHOODS)}")
        self.effects = check_effects(list(effects))
        self.likelihood = likelihood
        self.valve = valve
        self.fixed = dict(fixed or {})
        self.start = dict(start or {})
        self.options = dict(options)
        if self.start and likelihood != "output_error":
            raise ValueError("start values are an option of the output_error likelihood only")

    def fit(self, data: pd.DataFrame | RunData | str | os.PathLike[str]) -> ValveEstimator:
        """Fit to a run: a path (read by the loader), a DataFrame (validated) or, for the output error,
        the framework's prepared :class:`~valve_env.valveid.data.RunData` (used as it is, e.g. a
        training slice). Returns ``self``."""
        if isinstance(data, RunData):
            if self.likelihood != "output_error":
                raise ValueError("a prepared RunData is an input of the output_error likelihood only")
            self._fit_output_error(data)
            return self
        df = load_run(data, self.valve) if isinstance(data, (str, os.PathLike)) else validate_run(data,
                                                                                                  valve=self.valve)
        if self.likelihood == "ekf":
            self._fit_ekf(df)
        else:
            self._fit_output_error(RunData.from_frame(df, str(df.attrs.get("source", "run"))))
        return self

    def bootstrap(self, B: int = 16, seed: int = 0, params: tuple[str, ...] | list[str] | None = None
                  ) -> ValveEstimator:
        """The calibrated uncertainty of a fitted output-error estimator: the model-based bootstrap of the
        whole chain (:func:`valve_env.valveid.bootstrap.bootstrap`, ``B`` replicates, temperature
        smoothing included) with the pre-processing bracket, applied as the diagnosis applies it to a
        named effect (:func:`valve_env.valveid.bootstrap.apply_bootstrap`: ``std_`` of ``params``
        the bootstrap's sd, at least the inverse-Hessian/HAC sd, and ``params_`` bias-corrected where
        the bias is clear). ``params``: default the effects' parameters, or the base model's
        ``sigma``, ``F_hmax``, ``p_bset`` without effects. Returns ``self``; ``bootstrap_`` holds the
        replicates and their summary, ``std_from_`` where each sd came from. With stiction, the sd of the parameters
        not bootstrapped is withheld (:func:`valve_env.valveid.bootstrap.withhold_conditional_std`)."""

        self._check()
        if self.likelihood != "output_error":
            raise ValueError("the bootstrap is an option of the output_error likelihood")
        names = list(params) if params is not None else None
        if names is None and not self.effects:
            names = ["sigma", "F_hmax", "p_bset"]
        b = bootstrap(self.backend_, self.data_, self.result_, B=B, seed=seed, names=names)
        self.std_from_ = apply_bootstrap(self.backend_, self.data_, self.result_, b)
        if "band_mm" in b.names:
            withhold_conditional_std(self.result_, b.names)
        self.backend_.forget_paths()
        self.bootstrap_ = b
        self._estimates_from_result()
        return self

    def _estimates_from_result(self) -> None:
        """``params_`` and ``std_`` (the free parameters') as the output-error fit ``result_`` holds them."""
        self.params_ = dict(self.result_.params)
        self.std_ = {k: v for k, v in self.result_.std.items() if k not in self.fixed}

    def _fit_ekf(self, df: pd.DataFrame) -> None:

        model = effect_model(self.effects, valve=self.valve) if self.effects else base_valve_model(self.valve)
        est = MLEstimator(model, fixed=self.fixed, **self.options).fit(df)
        self.backend_: Any = est
        for name in ("params_", "std_", "loglik_", "n_obs_", "n_free_", "converged_", "rms_"):
            setattr(self, name, getattr(est, name))

    def _fit_output_error(self, run: RunData) -> None:

        model = Model(tuple(self.effects), self.valve)
        res = model.fit(run, start=self.start or None, fixed=self.fixed or None, **self.options)
        model.forget_paths()  # the fit's kept valve paths are not the estimator's to hold
        self.backend_ = model
        self.result_ = res
        self.data_ = run
        self._estimates_from_result()
        self.loglik_ = float(res.loglik)
        self.n_obs_ = int(res.n)
        self.n_free_ = int(res.n_free)
        self.converged_ = bool(res.converged)
        self.rms_ = {"x_mm": float(res.rms_mm)}


__all__ = ["ValveEstimator", "LIKELIHOODS"]
