"""The breakaway travel S of a stem that slips less than it sticks (J < S): the (S, J) profile.

Stiction's band is measured from the slips of the opening (:func:`valve_env.valveid.stiction.jump_band`).
Under the project's stick-slip (J = S, :mod:`valve_env.physics.stickslip`) a slip is the band. A stem whose
slip J is shorter than its breakaway travel S (the independent simulator's ``force`` valve, Karnopp's
static and Coulomb friction: J = S (1 - r) / (1 + r)) slips J, and the rest of S, the lag (S - J) / 2 of the
moving stem behind its demand, looks like more Dahl hysteresis (a larger ``F_hmax``), with which it trades
off: a saturated Dahl branch and a lagging stem move the opening alike. What tells them apart is the Dahl
friction's transient after a reversal: the friction is still turning over when the stem breaks away (the
demand moves the band within a few hundredths of a kelvin, the friction turns over in ``F_hmax / sigma``,
about 0.2 K), and a lag moves the whole branch while a larger ``F_hmax`` moves only its saturated part.

:func:`sj_profile` profiles the ratio k = S / J on a grid: J is held at the slips' band, S = k J, and at each
k the hysteresis of the moving branches, ``2 F_hmax / C + (S - J)``, is kept at the fit's (``F_hmax`` lowered
by ``C (k - 1) J / 2``, then the best of a few offsets about that); the other parameters stay at the fit's.
The likelihood is the open-loop one: the (S, J) stem (:func:`stick_simulate_sj`) on the fitted valve's demand,
its residual an Ornstein-Uhlenbeck process plus white noise (:func:`valve_env.ident.kalman.ou_loglik`,
the diagnosis's output-error likelihood without the stick-slip filter, which holds J = S). So the profile
asks one question: with the same hysteresis, is part of it a lag of the stem (S > J) rather than friction?
The estimate is the grid's best k; its sd the half-rise width of the profile (the k whose log-likelihood
lies above halfway between the J = S model's and the best, widened by one grid step, over 2 sqrt(2 ln 2)):
the open-loop likelihood is rough (a slip that moves by a sub-step moves the likelihood by tens), so its
curvature is not a sd.

The open-loop profile is not a test of J < S: on 36 development runs whose valve has J = S it put S / J
above 1 on 28, up to 2.0 (a stem that re-sticks after every slip lags its demand by half a step on average,
and the fitted demand's error near the reversals is of the lag's size); on 12 of 13 ``force`` runs (S / J 1.8-3.3)
it read 1.75-2.75, S within -31 to +16 %. The diagnosis's bootstrap takes as the band the S of the stick-slip
filter's profile (:func:`sj_filter_loglik`) where it reads at least 1.75 and the stem stuck longer
than it slipped, that reading corrected for its low reading on the fitted valve
(:func:`valve_env.valveid.bootstrap.breakaway_band`, :func:`~valve_env.valveid.bootstrap.calibrated_ratio`;
docs/diagnosis.md, "What ``band_mm`` is on a valve with J < S").
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np

from valve_env.ident.kalman import ou_loglik
from valve_env.valveid.oe import stick_simulate_sj

if TYPE_CHECKING:
    from valve_env.valveid.data import RunData
    from valve_env.valveid.fitting import Model

#: the ratios S / J profiled (a force-law valve with Coulomb / static friction r has S / J = (1 + r) / (1 - r):
#: 3 at r = 0.5; the slips' band reads J a little long, so the measured ratio is lower)
PROFILE_RATIOS: tuple[float, ...] = (1.0, 1.25, 1.5, 1.75, 2.0, 2.25, 2.5, 2.75, 3.0, 3.5, 4.0)
#: offsets (N) about the hysteresis-keeping F_hmax scanned at each ratio (:func:`sj_profile`)
PROFILE_F_SCAN: tuple[float, ...] = tuple(float(v) for v in np.linspace(-0.15, 0.15, 7))
_FWHM = 2.0 * math.sqrt(2.0 * math.log(2.0))


def sj_loglik(model: Model, data: RunData, values: dict[str, float], S: float, J: float) -> float:
    """The open-loop log-likelihood of the opening under the (S, J) stem on ``model``'s valve with ``values``
    (module docstring): ``model.simulate``'s stem with band S and slip J, its residual scored by
    :func:`~valve_env.ident.kalman.ou_loglik`."""
    xs = model.simulate(data, {**values, "band_mm": S}, slip=J)[0]
    mask = np.ones(len(data), dtype=np.bool_)
    ll, _, _ = ou_loglik(data.t, data.x - xs, values["s_w"], values["s_e"], values["tau_e"], mask, data.x_scale)
    return float(ll)


def sj_filter_loglik(model: Model, data: RunData, values: dict[str, float], S: float, J: float) -> float:
    """The stick-slip filter's log-likelihood of the opening (``model.loglik``, the diagnosis's own, with its
    measured slip decision) under the (S, J) stem of :mod:`valve_env.physics.stickslip`: a resting stem breaks
    away where the demand is ``(S + J) / 2`` from it (the filter's band; from a reversal the demand has then
    travelled S), slips ``J`` and moves ``(S - J) / 2`` behind the demand (the filter's lag). At ``J = S`` this is
    the diagnosis's likelihood exactly."""
    B = 0.5 * (S + J) if J < S else S
    return model.loglik(data, {**values, "band_mm": B}, slip=J if J < S else -1.0)


class SJLoglik(Protocol):
    def __call__(self, model: Model, data: RunData, values: dict[str, float], S: float, J: float) -> float: ...


@dataclass(frozen=True)
class SJProfile:
    """The (S, J) profile of a run (:func:`sj_profile`); lengths in mm."""

    J_mm: float
    ratios: tuple[float, ...]
    #: the open-loop log-likelihood at each ratio, its nuisance parameters refitted
    loglik: tuple[float, ...]
    #: the best ratio S / J, and its sd (half-rise width of the profile)
    ratio: float
    ratio_sd: float
    #: the F_hmax refitted at the best ratio (N)
    F_hmax: float

    @property
    def S_mm(self) -> float:
        return self.ratio * self.J_mm

    def to_json(self) -> dict[str, object]:
        """The profile's reading: its S / J and sd, the F_hmax (N) there, and the log-likelihood at each ratio
        less the J = S model's."""
        ll0 = self.loglik[0]
        return {"profile_S_over_J": float(self.ratio), "profile_S_over_J_sd": float(self.ratio_sd),
                "profile_F_hmax_N": float(self.F_hmax),
                "profile_loglik": {f"{k:g}": float(v - ll0) for k, v in zip(self.ratios, self.loglik, strict=True)}}


def spring_rate(model: Model, data: RunData) -> float:
    """The stem's spring rate C (N/mm) at the run's median differential pressure: the force balance's
    denominator (docs/reference.md, section 1; ``C_v + C_i + C_b + K_f dp``, dp in MPa)."""
    v = model.valve
    return float(v.C_v + v.C_i + v.C_b + v.K_f * float(np.median(data.dp)) * 1e-4)


def sj_profile(model: Model, data: RunData, values: dict[str, float], J: float | None = None,
               ratios: tuple[float, ...] = PROFILE_RATIOS, f_scan: tuple[float, ...] = PROFILE_F_SCAN,
               loglik: SJLoglik = sj_loglik) -> SJProfile:
    """The profile of S / J (module docstring) for a fit ``values`` of ``model`` (with stiction) to ``data``;
    ``J`` defaults to the fitted band (the slips'). At each ratio k the hysteresis of the moving branches,
    ``2 F_hmax / C + (S - J)``, is kept at the fit's: ``F_hmax`` is the fit's less ``C (k - 1) J / 2``, then
    the best of the offsets ``f_scan`` (N) about that; the other parameters stay at the fit's. ``loglik`` is the
    open-loop likelihood (:func:`sj_loglik`) or the stick-slip filter's (:func:`sj_filter_loglik`)."""
    if not ratios or ratios[0] != 1.0 or any(b <= a for a, b in zip(ratios, ratios[1:], strict=False)):
        raise ValueError("ratios must be increasing and start at 1 (the J = S model)")
    J = float(values["band_mm"] if J is None else J)
    if not (math.isfinite(J) and J > 0.0):
        raise ValueError(f"J must be finite and > 0, got {J!r}")
    C = spring_rate(model, data)
    ll = np.empty(len(ratios))
    F = np.empty(len(ratios))
    for i, k in enumerate(ratios):
        F0 = float(values["F_hmax"]) - C * (k - 1.0) * J / 2.0
        best = -math.inf
        for dF in f_scan:
            f = max(F0 + dF, 0.05 * float(values["F_hmax"]))
            v = loglik(model, data, {**values, "F_hmax": f}, k * J, J)
            if v > best:
                best, F[i] = v, f
        ll[i] = best
    i = int(np.argmax(ll))
    rise = float(ll[i] - ll[0])
    if i == 0 or not rise > 0.0:
        return SJProfile(J, tuple(ratios), tuple(map(float, ll)), 1.0, 0.0, float(F[0]))
    above = np.flatnonzero(ll >= ll[0] + 0.5 * rise)
    step = float(np.median(np.diff(ratios)))
    width = float(ratios[above[-1]] - ratios[above[0]]) + step
    return SJProfile(J, tuple(ratios), tuple(map(float, ll)), float(ratios[i]), width / _FWHM, float(F[i]))


__all__ = ["PROFILE_F_SCAN", "PROFILE_RATIOS", "SJLoglik", "SJProfile", "sj_filter_loglik", "sj_loglik", "sj_profile",
           "spring_rate",
           "stick_simulate_sj"]
