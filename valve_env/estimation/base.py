"""The estimator interface of the identification framework (scikit-learn style).

Every estimator of the project follows it: ``fit(data)`` returns the estimator itself, and what it
learned ends in ``_`` (``params_``, ``std_``, ``loglik_``, ``n_obs_``, ``n_free_``, ``aic_``,
``bic_``, ``converged_``). :class:`valve_env.estimation.fit.MLEstimator` (the EKF likelihood of an
:class:`~valve_env.estimation.model.SDEModel`) and
:class:`valve_env.estimation.estimator.ValveEstimator` (the valve with effects of the registry,
either likelihood) implement it.
"""

from __future__ import annotations

from typing import Any

import pandas as pd


class NotFittedError(RuntimeError):
    """The estimator is used before ``fit``."""


class Estimator:
    """Base class: ``fit`` returns ``self``; learned attributes end in ``_``."""

    params_: dict[str, float]
    std_: dict[str, float]
    loglik_: float
    n_obs_: int
    n_free_: int
    aic_: float
    bic_: float
    converged_: bool

    def fit(self, data: Any) -> Estimator:  # pragma: no cover - interface
        raise NotImplementedError

    def _check(self) -> None:
        if not hasattr(self, "params_"):
            raise NotFittedError("call fit(data) first")

    def summary(self) -> pd.DataFrame:
        """Table of estimates: estimate, std and t-statistic per parameter."""
        self._check()
        rows = []
        for name, value in self.params_.items():
            sd = self.std_.get(name, float("nan"))
            rows.append({"parameter": name, "estimate": value, "std": sd,
                         "t": value / sd if sd == sd and sd > 0 else float("nan")})
        return pd.DataFrame(rows).set_index("parameter")


__all__ = ["Estimator", "NotFittedError"]
