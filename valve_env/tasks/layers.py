"""Task layers: reward terms, KPIs and observations that a task adds on top of
the plant, kept apart from the physics (valve_env.simulator is not touched).

A layer sees what a meter and a tariff would see: the step outputs of the
simulator kernel (rows ``simulator.O_*``: heat, return and supply
temperature, flow) and the step index. The same vectorised methods serve the
single env (a batch of one) and the batched env, so both compute the same
numbers (tests/tasks). See docs/tasks.md.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any, ClassVar, Self

import numpy as np

from valve_env import simulator as sim
from valve_env.params import ConfigError, _from_mapping, check_fields, param
from valve_env.scenario import ScenarioParams, network_load, supply_plan


class TaskLayer:
    """The identity layer: no reward term, no KPI, no observation (the three original ids)."""

    kpi_names: ClassVar[tuple[str, ...]] = ()
    obs_names: ClassVar[tuple[str, ...]] = ()
    n_acc: ClassVar[int] = 0

    def obs_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper bounds of the extra observations."""
        return np.zeros(0, np.float32), np.zeros(0, np.float32)

    def step(
        self, k: np.ndarray, out: np.ndarray, dt_s: float, acc: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """The reward added for the step that started at step index ``k`` (n,) with step
        outputs ``out`` (n, N_OUT), and the step's increments of the layer's accumulators (n, n_acc);
        ``acc`` (n, n_acc) are the accumulators before the step (a layer whose charge depends on
        the episode so far, such as a peak, reads them)."""
        n = out.shape[0]
        return np.zeros(n), np.zeros((n, self.n_acc))

    def settle(self, stored_change_J: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The reward added at an episode's last step for the change of the heat stored in the
        tank since the reset (n,), J, and the accumulator increments (n, n_acc): none here."""
        n = np.shape(stored_change_J)[0]
        return np.zeros(n), np.zeros((n, self.n_acc))

    def kpis(self, acc: np.ndarray) -> dict[str, float]:
        """The task KPIs from one env's accumulators (n_acc,)."""
        return {}

    def observation(self, k: np.ndarray, acc: np.ndarray | None = None) -> np.ndarray:
        """The extra observations (n, len(obs_names)) at step index ``k`` (n,), with the
        accumulators ``acc`` (n, n_acc) of the episode so far."""
        return np.zeros((np.shape(k)[0], 0), np.float32)


@dataclass(frozen=True)
class DistrictHeatingTariff:
    """A district-heating bill: a time-varying heat price and a return-temperature tariff.

    | field | unit | meaning (default, source: docs/tasks.md) |
    |---|---|---|
    | price_eur_MWh | EUR/MWh | mean heat price; 80 (Danish consumer DH prices' variable part) |
    | price_min_rel, price_max_rel | - | price at the lowest and highest load / mean; 0.6, 1.5 (peak-load pricing) |
    | surcharge_per_K | 1/K | surcharge on the energy bill per K of return above the reference; 0.01 |
    | T_return_ref_C | degC | return temperature that pays no surcharge; 40 (REFA Energi Holeby) |
    | w_eur | 1/EUR | reward weight of the bill; 100 (1 cent costs 1) |
    | forecast_h | h | horizons of the price and supply-plan forecasts in the observation; (1, 3, 6) |
    """

    price_eur_MWh: float = param(80.0, 0.0, None, "EUR/MWh")
    price_min_rel: float = param(0.6, 0.0, None, "-")
    price_max_rel: float = param(1.5, 0.0, None, "-")
    surcharge_per_K: float = param(0.01, 0.0, None, "1/K")
    T_return_ref_C: float = param(40.0, 0.0, None, "degC")
    w_eur: float = param(100.0, 0.0, None, "1/EUR")
    forecast_h: tuple[float, ...] = (1.0, 3.0, 6.0)

    def __post_init__(self) -> None:
        check_fields(self)  # the scalar fields, against their param() ranges
        if not all(np.isfinite(x) and x >= 0 for x in self.forecast_h):
            raise ConfigError(f"DistrictHeatingTariff.forecast_h must be finite and >= 0, got {self.forecast_h!r}")
        if not self.price_min_rel <= self.price_max_rel:
            raise ConfigError("DistrictHeatingTariff.price_min_rel must be <= price_max_rel")
        object.__setattr__(self, "forecast_h", tuple(float(x) for x in self.forecast_h))

    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | None) -> Self:
        data = dict(data or {})
        horizons = data.pop("forecast_h", None)
        base = _from_mapping(cls, data)
        if horizons is None:
            return base
        try:
            hs = tuple(float(h) for h in horizons)
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"DistrictHeatingTariff.forecast_h must be a list of hours, got {horizons!r}") from exc
        return cls(**{**{f.name: getattr(base, f.name) for f in fields(cls)}, "forecast_h": hs})

    def price(self, t_s: np.ndarray | float) -> np.ndarray:
        """The heat price at times ``t_s`` (s after midnight of day 0), EUR/MWh: it follows the
        network's load (:func:`valve_env.scenario.network_load`), as a peak-load price does."""
        rel = self.price_min_rel + (self.price_max_rel - self.price_min_rel) * network_load(t_s)
        # normalise the daily mean to price_eur_MWh
        return self.price_eur_MWh * rel / _mean_rel(self.price_min_rel, self.price_max_rel)


def _mean_rel(lo: float, hi: float) -> float:
    """The daily mean of ``lo + (hi - lo) load(t)``."""
    grid = np.arange(0.0, 86400.0, 60.0)
    return float(np.mean(lo + (hi - lo) * network_load(grid)))


class DistrictHeatingLayer(TaskLayer):
    """The bill of :class:`DistrictHeatingTariff` as a cost (EUR) and a reward term,
    and the operator's forecasts of price and supply temperature as observations.

    Per step of length dt with mean heat power P (W) and flow-weighted return
    temperature T_ret, at the price p(t) of the step's start:

        energy_eur = p(t) P dt / 3.6e9
        tariff_eur = energy_eur * surcharge_per_K * max(0, T_ret - T_return_ref_C)
        reward    += -w_eur (energy_eur + tariff_eur)

    (utilities apply the surcharge to a year's flow-weighted mean return;
    here it applies step by step, which makes it a per-step incentive.)

    At the episode's last step the heat stored in the tank is settled: the
    change since the reset is paid (a deficit) or credited (a surplus) at the
    tariff's mean price, ``storage_eur = price_eur_MWh x (E_0 - E_end)``. A
    real installation's day does not end at midnight: a tank left colder is
    recharged the next day. Without it a controller that sees the end coming
    (the oracle) saves by emptying the tank (docs/tasks.md).
    """

    kpi_names: ClassVar[tuple[str, ...]] = (
        "cost_eur", "energy_cost_eur", "return_tariff_eur", "storage_settlement_eur", "mean_price_eur_MWh")
    n_acc: ClassVar[int] = 4  # energy EUR, tariff EUR, heat J, storage settlement EUR

    def __init__(self, tariff: DistrictHeatingTariff, scenario: ScenarioParams, dt_s: float) -> None:
        self.tariff = tariff
        self.scenario = scenario
        self.dt_s = float(dt_s)
        hs = [f"{h:g}h" for h in tariff.forecast_h]
        # per instance: the tariff's forecast hours
        self.obs_names = (  # type: ignore[misc]
            "price_eur_MWh", *(f"price_{h}_eur_MWh" for h in hs), *(f"supply_plan_{h}_C" for h in hs))
        # the price of every step of a day, tabled (the price repeats daily)
        per_day = int(round(86400.0 / self.dt_s))
        self._price = tariff.price(np.arange(per_day) * self.dt_s)
        self._per_day = per_day
        # the observation's forecast columns of every step of a day, tabled likewise (the
        # operator's plan repeats daily): looked up per step, not recomputed
        steps = np.array([int(round(h * 3600.0 / self.dt_s)) for h in tariff.forecast_h], np.int64)
        grid = np.arange(per_day, dtype=np.int64)
        self._obs_table = np.concatenate([
            self._price[:, None],
            self._price[(grid[:, None] + steps[None, :]) % per_day],
            supply_plan(scenario, ((grid[:, None] + steps[None, :]) % per_day) * self.dt_s),
        ], axis=1).astype(np.float32)

    def obs_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        m = len(self.tariff.forecast_h)
        lo = np.array([0.0] * (m + 1) + [-20.0] * m, np.float32)
        hi = np.array([2000.0] * (m + 1) + [150.0] * m, np.float32)
        return lo, hi

    def price_at(self, k: np.ndarray) -> np.ndarray:
        """The price (EUR/MWh) in force during step index ``k``."""
        return self._price[np.asarray(k, dtype=np.int64) % self._per_day]

    def step(
        self, k: np.ndarray, out: np.ndarray, dt_s: float, acc: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        t = self.tariff
        inc = np.zeros((out.shape[0], self.n_acc))  # a subclass's further columns start at zero
        heat_J = inc[:, 2]
        np.multiply(out[:, sim.O_HEAT_W], dt_s, out=heat_J)
        energy = inc[:, 0]
        np.multiply(self.price_at(k), heat_J, out=energy)
        energy /= 3.6e9
        excess = np.maximum(out[:, sim.O_T_RET] - t.T_return_ref_C, 0.0)
        np.multiply(energy, t.surcharge_per_K * excess, out=inc[:, 1])
        return -t.w_eur * (energy + inc[:, 1]), inc

    def settle(self, stored_change_J: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        eur = -self.tariff.price_eur_MWh * np.asarray(stored_change_J, dtype=float) / 3.6e9
        acc = np.zeros((eur.shape[0], self.n_acc))
        acc[:, 3] = eur
        return -self.tariff.w_eur * eur, acc

    def kpis(self, acc: np.ndarray) -> dict[str, float]:
        heat_MWh = acc[2] / 3.6e9
        return {
            "cost_eur": float(acc[0] + acc[1] + acc[3]),
            "energy_cost_eur": float(acc[0]),
            "return_tariff_eur": float(acc[1]),
            "storage_settlement_eur": float(acc[3]),
            "mean_price_eur_MWh": float(acc[0] / heat_MWh) if heat_MWh > 0 else float("nan"),
        }

    def observation(self, k: np.ndarray, acc: np.ndarray | None = None) -> np.ndarray:
        return self._obs_table[np.asarray(k, dtype=np.int64) % self._per_day]


@dataclass(frozen=True)
class PowerChargeTariff(DistrictHeatingTariff):
    """:class:`DistrictHeatingTariff` plus a power charge on the highest hourly mean power.

    | field | unit | meaning (default, source: docs/tasks.md, "ThermoValveDistrictHeatingPower-v0") |
    |---|---|---|
    | power_eur_kW_day | EUR/(kW day) | daily share of the charge per kW of the day's highest hourly mean; 0.192 |

    The basis is SEVAB Strängnäs Energi's (Prislista 2: the billed power is the mean of the five
    highest hourly powers metered in the winter before); the rate is a year's power charge per kW
    against the winter energy price of Swedish utilities, median 0.88 MWh per kW-year (Lidköping
    Energi 2025: 795 kr/kW-yr, 90.8 ore/kWh; range 0.61-2.28 over Halmstad Energi och Miljö,
    Karlskoga, Söderhamn Nära, Oxelö, Jönköping and Bodens Energi), at the task's 80 EUR/MWh:
    70.1 EUR per kW-year, a 365th of it a day.
    """

    power_eur_kW_day: float = param(0.192, 0.0, None, "EUR/(kW day)")


#: the bound of the heat meter's hourly readings in the observation, kW, either way: the coil's heat
#: flow m cp (T_supply - T_return) takes the sign of the supply's excess over the store, and its size is
#: bounded by the same coil (UA about 800 W/K: tens of kW at most) whichever way the heat goes
METER_KW = 100.0


class DistrictHeatingPowerLayer(DistrictHeatingLayer):
    """:class:`DistrictHeatingLayer`'s bill plus a power charge on the day's highest hourly
    mean power (clock hours: energy metered in the hour / 1 h), as a heat meter's hourly
    values bill it:

        power_eur = power_eur_kW_day x max over the day's hours of E_hour / 1 h   (kW)

    charged as it grows: a step that raises the running maximum of the current hour's energy so
    far pays the rise, so the episode's sum is exactly the charge on its highest hour, and the
    reward stays a per-step sum. Observed (two more columns): the current hour's energy so far
    as a mean power over the hour (kW) and the highest hourly mean so far (kW): the meter's
    readings, which the customer sees. The heat is net, as the bill's energy: while the supply
    is colder than the store the coil gives heat back (a negative step heat), so the hour so far
    can be negative (docs/tasks.md, "ThermoValveDistrictHeatingPower-v0").
    """

    kpi_names: ClassVar[tuple[str, ...]] = (*DistrictHeatingLayer.kpi_names, "power_charge_eur", "peak_hourly_kW")
    n_acc: ClassVar[int] = 7  # as DistrictHeatingLayer, then hour energy J, peak hour energy J, power EUR

    tariff: PowerChargeTariff

    def __init__(self, tariff: PowerChargeTariff, scenario: ScenarioParams, dt_s: float) -> None:
        super().__init__(tariff, scenario, dt_s)
        self.obs_names = (*self.obs_names, "hour_so_far_kW", "peak_hourly_kW")  # type: ignore[misc]
        self._per_hour = int(round(3600.0 / self.dt_s))

    def obs_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The meter's two columns: the current hour's net heat in [-METER_KW, METER_KW] (the coil
        gives heat back while the supply is colder than the store: a negative step heat, which the
        bill nets as it nets the energy), the day's highest hour in [0, METER_KW] (a maximum
        starting at zero)."""
        lo, hi = super().obs_bounds()
        return (np.concatenate([lo, [-METER_KW, 0.0]]).astype(np.float32),
                np.concatenate([hi, [METER_KW, METER_KW]]).astype(np.float32))

    def _hour_so_far_J(self, k: np.ndarray, acc: np.ndarray) -> np.ndarray:
        """The heat metered in the current clock hour before step index ``k`` (J): the hour's
        accumulator, or zero where ``k`` starts a new hour."""
        return np.where(np.asarray(k, dtype=np.int64) % self._per_hour == 0, 0.0, acc[:, 4])

    def step(
        self, k: np.ndarray, out: np.ndarray, dt_s: float, acc: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        if acc is None:
            raise ValueError("DistrictHeatingPowerLayer.step needs the accumulators (acc)")
        r, inc = super().step(k, out, dt_s)  # (n, n_acc): the bill's four columns, the rest zero
        hour = self._hour_so_far_J(k, acc) + inc[:, 2]
        peak = np.maximum(acc[:, 5], hour)
        inc[:, 4] = hour - acc[:, 4]
        inc[:, 5] = peak - acc[:, 5]
        inc[:, 6] = self.tariff.power_eur_kW_day * inc[:, 5] / 3.6e6
        return r - self.tariff.w_eur * inc[:, 6], inc

    def kpis(self, acc: np.ndarray) -> dict[str, float]:
        k = super().kpis(acc)
        k["cost_eur"] = float(k["cost_eur"] + acc[6])
        return {**k, "power_charge_eur": float(acc[6]), "peak_hourly_kW": float(acc[5] / 3.6e6)}

    def observation(self, k: np.ndarray, acc: np.ndarray | None = None) -> np.ndarray:
        base = super().observation(k)
        n = base.shape[0]
        meter = np.zeros((n, 2), np.float32) if acc is None else np.stack(
            [self._hour_so_far_J(k, acc) / 3.6e6, acc[:, 5] / 3.6e6], axis=1).astype(np.float32)
        return np.concatenate([base, meter], axis=1)


def make_layer(name: str | None, params: Mapping[str, Any], scenario: ScenarioParams, dt_s: float) -> TaskLayer:
    """The task layer called ``name`` ("district_heating", "district_heating_power" or None) with
    its parameters."""
    if name is None:
        return TaskLayer()
    if name == "district_heating":
        return DistrictHeatingLayer(DistrictHeatingTariff.from_dict(params), scenario, dt_s)
    if name == "district_heating_power":
        return DistrictHeatingPowerLayer(PowerChargeTariff.from_dict(params), scenario, dt_s)
    raise ConfigError(f"unknown task layer {name!r}; known: district_heating, district_heating_power")


__all__ = ["METER_KW", "DistrictHeatingLayer", "DistrictHeatingPowerLayer", "DistrictHeatingTariff",
           "PowerChargeTariff", "TaskLayer", "make_layer"]
