"""Physical parameters of the valve, the sensor bulb and the tank.

Frozen dataclasses with units in their docstrings and the source of every
default beside it. The physics functions take the packed float vectors made by
``to_array()`` so that the same code runs in NumPy and compiled by numba.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any, ClassVar

import numpy as np

# Indices into the packed valve parameter vector (ValveParams.to_array()).
I_A_B, I_C_V, I_C_I, I_C_B, I_A_S, I_A_K, I_K_F = 0, 1, 2, 3, 4, 5, 6
I_SIGMA, I_F_HMAX, I_P_BSET = 7, 8, 9
I_ANT_A, I_ANT_B, I_ANT_C = 10, 11, 12
I_DP_K_SP, I_DP_S_SP, I_STROKE, I_KVS, I_LEAK = 13, 14, 15, 16, 17
N_VALVE = 18


class ConfigError(ValueError):
    """An invalid parameter or configuration value; the message names it."""


def _check_finite_positive(obj: Any, names: tuple[str, ...], allow_zero: tuple[str, ...] = ()) -> None:
    for f in fields(obj):
        v = getattr(obj, f.name)
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            continue
        if not math.isfinite(v):
            raise ConfigError(f"{type(obj).__name__}.{f.name} must be finite, got {v!r}")
        if f.name in names and (v < 0 or (v == 0 and f.name not in allow_zero)):
            raise ConfigError(f"{type(obj).__name__}.{f.name} must be > 0, got {v!r}")


def _from_mapping(cls: type, data: Mapping[str, Any] | None) -> Any:
    if data is None:
        return cls()
    if isinstance(data, cls):
        return data
    if not isinstance(data, Mapping):
        raise ConfigError(f"{cls.__name__} must be a mapping of field names to values, got {type(data).__name__}")
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ConfigError(f"unknown {cls.__name__} field(s) {unknown}; known: {sorted(known)}")
    kw = {}
    for k, v in data.items():
        try:
            kw[k] = float(v) if not isinstance(v, (str, bool)) and v is not None else v
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"{cls.__name__}.{k} must be a number, got {v!r}") from exc
    return cls(**kw)


@dataclass(frozen=True)
class ValveParams:
    """Self-acting thermostatic valve (SPEC section 1; paper Tables 2-4).

    | field | unit | default source |
    |---|---|---|
    | A_b | mm^2 | bellows area, Table 2 |
    | C_v | N/mm | valve spring, Table 2 |
    | C_i | N/mm | setting spring, Table 2 |
    | C_b | N/mm | bellows spring, Table 2 (printed as a second "C_v") |
    | A_s | mm^2 | spindle area, Table 3 |
    | A_k | mm^2 | cone area, Table 3 |
    | K_f | mm | flow spring, Table 3 |
    | sigma | N/K | Dahl stiffness, Table 4 (sd 0.589) |
    | F_hmax | N | maximum friction force, Table 4 (sd 0.067) |
    | p_bset | MPa | bellows pressure at the set point, Table 4 (sd 0.000892) |
    | antoine_A, antoine_B, antoine_C | -, K, K | methanol vapour pressure, log10(p/bar) = A - B/(T/K + C); NIST |
    | dp_k_sp | MPa | calibration differential pressure, 100 mbar (SPEC default) |
    | dp_s_sp | MPa | calibration static pressure, 2 bar (SPEC default) |
    | stroke | mm | 2.0 (SPEC default) |
    | Kvs | m^3/h | 1.9, Danfoss AVTB DN15 class (SPEC default) |
    | leakage | - | 0.0002 = 0.02 % of Kvs (SPEC default) |
    """

    A_b: float = 1032.0
    C_v: float = 1.8
    C_i: float = 13.7
    C_b: float = 3.2
    A_s: float = 2.45
    A_k: float = 52.0
    K_f: float = 99.7
    sigma: float = 6.41
    F_hmax: float = 1.31
    p_bset: float = 0.0776
    antoine_A: float = 5.20409
    antoine_B: float = 1581.341
    antoine_C: float = -33.50
    dp_k_sp: float = 0.01
    dp_s_sp: float = 0.2
    stroke: float = 2.0
    Kvs: float = 1.9
    leakage: float = 0.0002

    #: Standard deviations of the paper's Table 4 estimates.
    TABLE4_STD: ClassVar[dict[str, float]] = {"sigma": 0.589, "F_hmax": 0.067, "p_bset": 0.000892}

    def __post_init__(self) -> None:
        _check_finite_positive(
            self,
            ("A_b", "C_v", "C_i", "C_b", "A_s", "A_k", "K_f", "sigma", "F_hmax", "p_bset", "stroke", "Kvs"),
        )
        if not 0.0 <= self.leakage < 1.0:
            raise ConfigError(f"ValveParams.leakage must be in [0, 1), got {self.leakage!r}")
        for name in ("K_f", "dp_k_sp", "dp_s_sp"):
            if getattr(self, name) < 0:
                raise ConfigError(f"ValveParams.{name} must be >= 0, got {getattr(self, name)!r}")

    def to_array(self) -> np.ndarray:
        """The packed float64 vector that the physics functions index (I_* constants)."""
        return np.array(
            [
                self.A_b, self.C_v, self.C_i, self.C_b, self.A_s, self.A_k, self.K_f,
                self.sigma, self.F_hmax, self.p_bset,
                self.antoine_A, self.antoine_B, self.antoine_C,
                self.dp_k_sp, self.dp_s_sp, self.stroke, self.Kvs, self.leakage,
            ],
            dtype=np.float64,
        )

    def replace(self, **changes: float) -> ValveParams:
        return dataclasses.replace(self, **changes)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | None) -> ValveParams:
        return _from_mapping(cls, data)

    def to_dict(self) -> dict[str, float]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True)
class BulbParams:
    """The sensor bulb in the tank: first-order heat dynamics tau dT_g/dt = T_tank - T_g.

    | field | unit | default source |
    |---|---|---|
    | tau_s | s | 40 s, SPEC section 5 (a liquid-filled immersion bulb in still water) |
    | height | - | relative height of the bulb in the tank, 0 bottom .. 1 top; 0.7 (upper third, a thermostat pocket) |
    """

    tau_s: float = 40.0
    height: float = 0.7

    def __post_init__(self) -> None:
        _check_finite_positive(self, ("tau_s",))
        if not 0.0 <= self.height <= 1.0:
            raise ConfigError(f"BulbParams.height must be in [0, 1], got {self.height!r}")

    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | None) -> BulbParams:
        return _from_mapping(cls, data)

    def to_dict(self) -> dict[str, float]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True)
class TankParams:
    """Stratified domestic hot-water storage tank with an internal coil.

    | field | unit | default source |
    |---|---|---|
    | volume_l | l | 200 l, SPEC section 5 |
    | n_layers | - | 8 (SPEC asks for at least 6) |
    | coil_layers | - | the coil occupies the lowest n layers: 4 = lower half (SPEC) |
    | UA_coil | W/K | 800 W/K, SPEC section 5 |
    | UA_loss | W/K | 1.9 W/K standing loss, SPEC section 5 (~ 45 W at 60/20 degC, ErP class B for 200 l) |
    | T_ambient | degC | 20, SPEC section 5 |
    | T_cold | degC | 10, SPEC section 5 and the EU tapping cycles |
    | cp | J/(kg K) | 4180, water; the tapping cycles' 4.18 kJ/(kg K) |
    | rho | kg/l | 1.0, as in the tapping cycles |
    | pump_eff | - | 0.3, wire-to-water efficiency of a small circulator (EU 622/2012 EEI range) |
    | dp_circuit_mbar | mbar | 150, pressure drop of coil and pipes at q_ref, pump head on top of the valve's dp |
    | q_ref_kgh | kg/h | 600, reference flow for dp_circuit_mbar |
    """

    volume_l: float = 200.0
    n_layers: int = 8
    coil_layers: int = 4
    UA_coil: float = 800.0
    UA_loss: float = 1.9
    T_ambient: float = 20.0
    T_cold: float = 10.0
    cp: float = 4180.0
    rho: float = 1.0
    pump_eff: float = 0.3
    dp_circuit_mbar: float = 150.0
    q_ref_kgh: float = 600.0

    def __post_init__(self) -> None:
        _check_finite_positive(
            self, ("volume_l", "UA_coil", "UA_loss", "cp", "rho", "pump_eff", "q_ref_kgh", "dp_circuit_mbar"),
            allow_zero=("UA_loss", "dp_circuit_mbar"),
        )
        if int(self.n_layers) != self.n_layers or self.n_layers < 6:
            raise ConfigError(f"TankParams.n_layers must be an integer >= 6, got {self.n_layers!r}")
        if int(self.coil_layers) != self.coil_layers or not 1 <= self.coil_layers <= self.n_layers:
            raise ConfigError(
                f"TankParams.coil_layers must be an integer in [1, n_layers={self.n_layers}], got {self.coil_layers!r}"
            )
        if self.pump_eff > 1.0:
            raise ConfigError(f"TankParams.pump_eff must be <= 1, got {self.pump_eff!r}")
        object.__setattr__(self, "n_layers", int(self.n_layers))
        object.__setattr__(self, "coil_layers", int(self.coil_layers))

    @property
    def layer_mass_kg(self) -> float:
        return self.volume_l * self.rho / self.n_layers

    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | None) -> TankParams:
        return _from_mapping(cls, data)

    def to_dict(self) -> dict[str, float]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


__all__ = [
    "ConfigError",
    "ValveParams",
    "BulbParams",
    "TankParams",
    "N_VALVE",
]
