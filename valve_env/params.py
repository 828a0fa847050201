"""Physical parameters of the valve, the sensor bulb and the tank.

Frozen dataclasses with units in their docstrings and the source of every
default beside it. The physics functions take the packed float vectors made by
``to_array()`` so that the same code runs in NumPy and compiled by numba.

Every field declares the values it accepts once, with :func:`param` (a range,
a unit and the physical reason for the range, kept in the field's
``metadata``); :func:`check_fields`, called by every parameter dataclass's
``__post_init__``, checks and normalises them, so that a bad value raises a
one-line :class:`ConfigError` naming the section and the field, e.g.
``valve.sigma must be a finite number in (0, 1000] N/K, got None``
(docs/configuration.md).
"""

from __future__ import annotations

import dataclasses
import math
import numbers
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

# Physical limits shared by the field ranges, the scenario and the observation box
# (valve_env.envs.thermovalve); docs/configuration.md gives the reasons.
#: differential pressure across the valve, mbar: 2 bar, above the rated maximum of small
#: self-acting valves; the network's disturbed dp is kept within [0, DP_MAX_MBAR]
DP_MAX_MBAR = 2000.0
#: primary supply temperature, degC: liquid water at district-heating pressures; a random
#: supply profile is kept within these limits, a daily one must lie within them
SUPPLY_LIMITS_C = (0.0, 140.0)
#: the tank's hot-water outflow, l/min: a DN32 outlet at 2 m/s (the velocity limit of
#: drinking-water installations), over ten of the EU cycles' taps (<= 10 l/min each) at once
DRAW_MAX_L_MIN = 100.0


class ConfigError(ValueError):
    """An invalid parameter or configuration value; the message names it."""


@dataclass(frozen=True)
class Spec:
    """The values one parameter accepts: declared once per field by :func:`param`.

    ``kind`` is ``"float"`` (a finite real number), ``"int"`` (an integer, also
    given as an integral float such as YAML's ``8.0``), ``"bool"`` or
    ``"choice"`` (one of ``choices``). Numbers must lie in ``[lo, hi]``
    (``lo_open``/``hi_open`` exclude an end). ``why`` is the physical reason
    for the range."""

    lo: float | None = None
    hi: float | None = None
    unit: str = "-"
    why: str = ""
    kind: str = "float"
    choices: tuple[Any, ...] = ()
    lo_open: bool = False
    hi_open: bool = False

    def describe(self) -> str:
        """The range as written in the docstring tables: ``[0, 1]``, ``(0, 1000]``, ``{S, M, L, none}``."""
        if self.kind == "choice":
            return "{" + ", ".join(str(c) for c in self.choices) + "}"
        if self.kind == "bool":
            return "{true, false}"
        return f"{'(' if self.lo_open else '['}{_g(self.lo)}, {_g(self.hi)}{')' if self.hi_open else ']'}"

    def _unit(self) -> str:
        return "" if self.unit in ("-", "") else f" {self.unit}"

    def check(self, where: str, value: Any) -> Any:
        """``value`` normalised (float, int, bool or the choice), or a one-line
        :class:`ConfigError` naming ``where`` (``section.field``)."""
        if self.kind == "choice":
            if isinstance(value, str) and value in self.choices:
                return value
            raise ConfigError(f"{where} must be one of {self.describe()}, got {value!r}")
        if self.kind == "bool":
            if isinstance(value, (bool, np.bool_)):
                return bool(value)
            raise ConfigError(f"{where} must be true or false, got {value!r}")
        what = "an integer" if self.kind == "int" else "a finite number"
        expect = f"{what} in {self.describe()}{self._unit()}"
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
            hint = ""
            if isinstance(value, str) and _looks_numeric(value):
                hint = " (YAML 1.1 reads 1e3 or 1.0e3 as text: write 1.0e+3 or 1000.0)"
            got = "None" if value is None else f"{type(value).__name__} {value!r}"
            raise ConfigError(f"{where} must be {expect}, got {got}{hint}")
        v = float(value)
        if not math.isfinite(v):
            raise ConfigError(f"{where} must be {expect}, got {value!r}")
        if self.kind == "int":
            if v != int(v):
                raise ConfigError(f"{where} must be {expect}, got {value!r}")
        if not self.contains(v):
            why = f" ({self.why})" if self.why else ""
            raise ConfigError(f"{where} must be in {self.describe()}{self._unit()}{why}, got {value!r}")
        return int(v) if self.kind == "int" else v

    def contains(self, v: float) -> bool:
        """Whether the number ``v`` is in the range."""
        if self.lo is not None and (v < self.lo or (self.lo_open and v == self.lo)):
            return False
        return not (self.hi is not None and (v > self.hi or (self.hi_open and v == self.hi)))


def _g(x: float | None) -> str:
    if x is None:
        return "inf"
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e15 else f"{x:g}"


def _looks_numeric(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True


def param(
    default: Any,
    lo: float | None = None,
    hi: float | None = None,
    unit: str = "-",
    why: str = "",
    *,
    kind: str = "float",
    choices: tuple[Any, ...] = (),
    lo_open: bool = False,
    hi_open: bool = False,
) -> Any:
    """A dataclass field with its accepted values: ``x: float = param(1.0, 0, 10, "mm", "reason")``.

    The :class:`Spec` is kept in the field's metadata (``metadata["spec"]``, with
    ``metadata["range"] = (lo, hi)`` and ``metadata["unit"]``) for
    :func:`check_fields`, the docs and any registry of parameters that reuses it."""
    spec = Spec(lo, hi, unit, why, kind, tuple(choices), lo_open, hi_open)
    return dataclasses.field(default=default, metadata={"spec": spec, "range": (lo, hi), "unit": unit})


def field_spec(cls: type, name: str) -> Spec:
    """The :class:`Spec` that field ``name`` of the parameter dataclass ``cls`` declares."""
    for f in fields(cls):
        if f.name == name:
            return f.metadata["spec"]
    raise KeyError(name)


def check_fields(obj: Any) -> None:
    """Check every declared field of the frozen dataclass ``obj`` against its
    :class:`Spec` and store the normalised value (float, int, bool); errors
    name ``<obj.SECTION>.<field>``. Call it first in ``__post_init__``."""
    section = getattr(obj, "SECTION", type(obj).__name__)
    for f in fields(obj):
        spec = f.metadata.get("spec")
        if spec is not None:
            object.__setattr__(obj, f.name, spec.check(f"{section}.{f.name}", getattr(obj, f.name)))


def _from_mapping(cls: type, data: Mapping[str, Any] | None) -> Any:
    if data is None:
        return cls()
    if isinstance(data, cls):
        return data
    section = getattr(cls, "SECTION", cls.__name__)
    if not isinstance(data, Mapping):
        raise ConfigError(f"{section} must be a mapping of field names to values, got {type(data).__name__} {data!r}")
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(map(str, data)) - known)
    if unknown:
        raise ConfigError(f"unknown {section} field(s) {unknown}; known: {sorted(known)}")
    return cls(**dict(data))


@dataclass(frozen=True)
class ValveParams:
    """Self-acting thermostatic valve (docs/reference.md, section 1; paper Tables 2-4).

    | field | unit | default source | range (why) |
    |---|---|---|---|
    | A_b | mm^2 | bellows area, Table 2 | [10, 20000] (radiator heads ~ 100 mm^2 to DN50 self-acting bellows) |
    | C_v | N/mm | valve spring, Table 2 | [0.01, 1000] (a spring, soft to stiff) |
    | C_i | N/mm | setting spring, Table 2 | [0.01, 1000] (a spring) |
    | C_b | N/mm | bellows spring, Table 2 (printed as a second "C_v") | [0.01, 1000] (a spring) |
    | A_s | mm^2 | spindle area, Table 3 | [0.01, 2000] (a spindle, thinner than the cone) |
    | A_k | mm^2 | cone area, Table 3 | [1, 20000] (DN10 to DN100 seats) |
    | K_f | mm | flow spring, Table 3 | [0, 10000] (0: no flow force) |
    | sigma | N/K | Dahl stiffness, Table 4 (sd 0.589) | (0, 1000] (the estimator searches 0.05 .. 500) |
    | F_hmax | N | maximum friction force, Table 4 (sd 0.067) | (0, 100] (the estimator searches 0.005 .. 50) |
    | p_bset | MPa | bellows pressure at the set point, Table 4 (sd 0.000892) | (0, 10] (a vapour charge; estimator 0.005 .. 1) |
    | antoine_A | - | methanol vapour pressure, log10(p/bar) = A - B/(T/K + C); NIST | [2, 8] (NIST fits of fill fluids) |
    | antoine_B | K | as antoine_A | [300, 4000] (NIST fits of fill fluids) |
    | antoine_C | K | as antoine_A | [-150, 50] (NIST fits; keeps T/K + C > 100 K above -20 degC) |
    | dp_k_sp | MPa | calibration differential pressure, 100 mbar (docs/reference.md default) | [0, 0.5] (0 .. 5 bar) |
    | dp_s_sp | MPa | calibration static pressure, 2 bar (docs/reference.md default) | [0, 2.5] (0 .. 25 bar, PN25) |
    | stroke | mm | 2.0 (docs/reference.md default) | [0.1, 50] (small to large valve strokes) |
    | Kvs | m^3/h | 1.9, Danfoss AVTB DN15 class (docs/reference.md default) | [0.05, 50] (DN10 to DN50 valves) |
    | leakage | - | 0.0002 = 0.02 % of Kvs (docs/reference.md default) | [0, 0.1] (tight .. 10 % of Kvs, a worn seat) |
    """  # noqa: E501

    SECTION: ClassVar[str] = "valve"

    A_b: float = param(1032.0, 10.0, 20000.0, "mm^2", "radiator heads ~ 100 mm^2 to DN50 self-acting bellows")
    C_v: float = param(1.8, 0.01, 1000.0, "N/mm", "a spring, soft to stiff")
    C_i: float = param(13.7, 0.01, 1000.0, "N/mm", "a spring, soft to stiff")
    C_b: float = param(3.2, 0.01, 1000.0, "N/mm", "a spring, soft to stiff")
    A_s: float = param(2.45, 0.01, 2000.0, "mm^2", "a spindle, thinner than the cone")
    A_k: float = param(52.0, 1.0, 20000.0, "mm^2", "DN10 to DN100 seats")
    K_f: float = param(99.7, 0.0, 10000.0, "mm", "0: no flow force")
    sigma: float = param(6.41, 0.0, 1000.0, "N/K", "the estimator searches 0.05 .. 500", lo_open=True)
    F_hmax: float = param(1.31, 0.0, 100.0, "N", "the estimator searches 0.005 .. 50", lo_open=True)
    p_bset: float = param(0.0776, 0.0, 10.0, "MPa", "a vapour charge; the estimator searches 0.005 .. 1",
                          lo_open=True)
    antoine_A: float = param(5.20409, 2.0, 8.0, "-", "NIST Antoine fits of fill fluids")
    antoine_B: float = param(1581.341, 300.0, 4000.0, "K", "NIST Antoine fits of fill fluids")
    antoine_C: float = param(-33.50, -150.0, 50.0, "K", "NIST Antoine fits; T/K + C > 100 K above -20 degC")
    dp_k_sp: float = param(0.01, 0.0, 0.5, "MPa", "0 .. 5 bar")
    dp_s_sp: float = param(0.2, 0.0, 2.5, "MPa", "0 .. 25 bar, PN25")
    stroke: float = param(2.0, 0.1, 50.0, "mm", "small to large valve strokes")
    Kvs: float = param(1.9, 0.05, 50.0, "m^3/h", "DN10 to DN50 valves")
    leakage: float = param(0.0002, 0.0, 0.1, "-", "tight .. 10 % of Kvs, a worn seat")

    #: Standard deviations of the paper's Table 4 estimates.
    TABLE4_STD: ClassVar[dict[str, float]] = {"sigma": 0.589, "F_hmax": 0.067, "p_bset": 0.000892}

    def __post_init__(self) -> None:
        check_fields(self)

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

    | field | unit | default source | range (why) |
    |---|---|---|---|
    | tau_s | s | 40 s, docs/reference.md, section 5 (a liquid-filled immersion bulb in still water) | [1, 3600] (a bare probe .. a bulb in a dry pocket) |
    | height | - | relative height of the bulb in the tank, 0 bottom .. 1 top; 0.7 (upper third, a thermostat pocket) | [0, 1] (inside the tank) |
    """  # noqa: E501

    SECTION: ClassVar[str] = "bulb"

    tau_s: float = param(40.0, 1.0, 3600.0, "s", "a bare probe .. a bulb in a dry pocket")
    height: float = param(0.7, 0.0, 1.0, "-", "inside the tank")

    def __post_init__(self) -> None:
        check_fields(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | None) -> BulbParams:
        return _from_mapping(cls, data)

    def to_dict(self) -> dict[str, float]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True)
class TankParams:
    """Stratified domestic hot-water storage tank with an internal coil.

    | field | unit | default source | range (why) |
    |---|---|---|---|
    | volume_l | l | 200 l, docs/reference.md, section 5 | [20, 10000] (a small under-sink tank .. a multi-family store) |
    | n_layers | - | 8 (docs/reference.md asks for at least 6) | [6, 100] (integer; the reference's minimum .. a fine model) |
    | coil_layers | - | the coil occupies the lowest n layers: 4 = lower half (docs/reference.md) | [1, 100] (integer, <= n_layers) |
    | UA_coil | W/K | 800 W/K, docs/reference.md, section 5 | [10, 20000] (a small coil .. a large exchanger) |
    | UA_loss | W/K | 1.9 W/K standing loss, docs/reference.md, section 5 (~ 45 W at 60/20 degC, ErP class B for 200 l) | [0, 200] (perfect .. poor insulation of a large tank) |
    | T_ambient | degC | 20, docs/reference.md, section 5 | [0, 50] (a frost-free room, the model has no ice .. a hot plant room) |
    | T_cold | degC | 10, docs/reference.md, section 5 and the EU tapping cycles | [1, 24] (cold mains; below the cycles' lowest draw temperature, 25 degC) |
    | cp | J/(kg K) | 4180, water; the tapping cycles' 4.18 kJ/(kg K) | [1500, 4500] (thermal oils .. water) |
    | rho | kg/l | 1.0, as in the tapping cycles | [0.7, 1.3] (liquids around water's density) |
    | pump_eff | - | 0.3, wire-to-water efficiency of a small circulator (EU 622/2012 EEI range) | [0.01, 1] (an efficiency) |
    | dp_circuit_mbar | mbar | 150, pressure drop of coil and pipes at q_ref, pump head on top of the valve's dp | [0, 2000] (0 .. 2 bar) |
    | q_ref_kgh | kg/h | 600, reference flow for dp_circuit_mbar | [10, 100000] (a small coil .. DN100) |
    | circ_kgh | kg/h | 0: no hot-water circulation loop (ThermoValveStickyCirculation-v0: 110, docs/tasks.md) | [0, 5000] (none .. a large building's circulation pump) |
    | circ_UA | W/K | 0: the circulation pipes' heat-loss coefficient, length x loss per metre and kelvin (ThermoValveStickyCirculation-v0: 16, 80 m at 0.2 W/(m K), Hamburg et al. 2021) | [0, 1000] (none .. kilometres of insulated pipe) |
    | circ_height | - | 0.5: height of the circulation return's connection, a fraction of the tank's height (an assumption: mid-height, above the coil) | [0, 1] (inside the tank) |

    Across sections (:class:`valve_env.config.EnvConfig`): the explicit update of a
    layer over one physics sub-step (control.dt_s / control.n_sub) may move at most
    half of the layer's heat capacity through the coil and the standing loss,
    (UA_coil / coil_layers + UA_loss / n_layers) dt_sub / (m_layer cp) <= 0.5, so
    that every layer temperature stays a mixture of the temperatures around it.
    """  # noqa: E501

    SECTION: ClassVar[str] = "tank"

    volume_l: float = param(200.0, 20.0, 10000.0, "l", "a small under-sink tank .. a multi-family store")
    n_layers: int = param(8, 6, 100, "-", "the reference's minimum .. a fine model", kind="int")
    coil_layers: int = param(4, 1, 100, "-", "within the tank's layers", kind="int")
    UA_coil: float = param(800.0, 10.0, 20000.0, "W/K", "a small coil .. a large exchanger")
    UA_loss: float = param(1.9, 0.0, 200.0, "W/K", "perfect .. poor insulation of a large tank")
    T_ambient: float = param(20.0, 0.0, 50.0, "degC", "a frost-free room, the model has no ice .. a hot plant room")
    T_cold: float = param(10.0, 1.0, 24.0, "degC", "cold mains; below the tapping cycles' lowest draw temperature")
    cp: float = param(4180.0, 1500.0, 4500.0, "J/(kg K)", "thermal oils .. water")
    rho: float = param(1.0, 0.7, 1.3, "kg/l", "liquids around water's density")
    pump_eff: float = param(0.3, 0.01, 1.0, "-", "an efficiency")
    dp_circuit_mbar: float = param(150.0, 0.0, 2000.0, "mbar", "0 .. 2 bar")
    q_ref_kgh: float = param(600.0, 10.0, 100000.0, "kg/h", "a small coil .. DN100")
    circ_kgh: float = param(0.0, 0.0, 5000.0, "kg/h", "none .. a large building's circulation pump")
    circ_UA: float = param(0.0, 0.0, 1000.0, "W/K", "none .. kilometres of insulated pipe")
    circ_height: float = param(0.5, 0.0, 1.0, "-", "inside the tank")

    def __post_init__(self) -> None:
        check_fields(self)
        if self.coil_layers > self.n_layers:
            raise ConfigError(
                f"tank.coil_layers must be at most tank.n_layers = {self.n_layers}, got {self.coil_layers!r}"
            )

    @property
    def layer_mass_kg(self) -> float:
        return self.volume_l * self.rho / self.n_layers

    @property
    def circ_layer(self) -> int:
        """The layer the circulation return enters (0 = bottom), from ``circ_height``."""
        return min(self.n_layers - 1, int(self.circ_height * self.n_layers))

    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | None) -> TankParams:
        return _from_mapping(cls, data)

    def to_dict(self) -> dict[str, float]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


__all__ = [
    "ConfigError",
    "DP_MAX_MBAR",
    "DRAW_MAX_L_MIN",
    "SUPPLY_LIMITS_C",
    "Spec",
    "param",
    "field_spec",
    "check_fields",
    "ValveParams",
    "BulbParams",
    "TankParams",
    "N_VALVE",
]
