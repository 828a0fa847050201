"""The valve file: a fitted or diagnosed valve in the environments' config format.

docs/reference.md, "The valve file"::

    valve:
      sigma: 6.41
      F_hmax: 1.31
      p_bset: 0.0776
      effects:
        stiction: {band_mm: 0.04}

``thermovalve fit RUN.csv --json F --valve-out V.yaml`` writes the base fit,
``thermovalve diagnose RUN.csv --json D --valve-out V.yaml`` the base parameters and the named
effects with their fitted values; ``gym.make(id, config="V.yaml")`` simulates that valve. The
file is an ordinary config file (valve_env.config) holding only the ``valve:`` section; the
effects are checked against the registry (valve_env.effects). Files are written through the
project's output policy (valve_env.outputs: never over an input, replaced only with --force,
atomically).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import fields
from pathlib import Path
from typing import Any

import yaml

from valve_env.config import EnvConfig, make_config
from valve_env.effects import Effects, parse_effects
from valve_env.outputs import OutputSet, PathLike
from valve_env.params import ConfigError, ValveParams, field_spec

#: the fitted base parameters, always written
BASE_FIELDS: tuple[str, ...] = ("sigma", "F_hmax", "p_bset")


def valve_mapping(params: Mapping[str, float], effects: Mapping[str, Mapping[str, float]] | Effects | None = None,
                  valve: ValveParams | None = None) -> dict[str, Any]:
    """The ``valve:`` mapping of a valve file: the fitted ``sigma, F_hmax, p_bset`` from ``params``,
    the other ValveParams fields where ``valve`` differs from the defaults, and ``effects`` (checked
    against the registry). Raises ConfigError naming a bad value."""
    base = valve if valve is not None else ValveParams()
    default = ValveParams()
    out: dict[str, Any] = {}
    for name in BASE_FIELDS:
        out[name] = float(field_spec(ValveParams, name).check(f"valve parameter {name}",
                                                              params.get(name, getattr(base, name))))
    for f in fields(ValveParams):
        if f.name not in out and getattr(base, f.name) != getattr(default, f.name):
            out[f.name] = float(getattr(base, f.name))
    eff = parse_effects(effects)
    ValveParams(**{**base.to_dict(), **{k: v for k, v in out.items()}})  # the base valve checks itself
    if eff:
        out["effects"] = eff.as_dict()
    return out


def valve_text(params: Mapping[str, float], effects: Mapping[str, Mapping[str, float]] | Effects | None = None,
               valve: ValveParams | None = None, source: str = "") -> str:
    """The valve file's text (YAML) for :func:`valve_mapping`'s arguments, with a comment naming
    ``source``."""
    head = f"# {source}\n" if source else ""
    body = yaml.safe_dump({"valve": valve_mapping(params, effects, valve)}, sort_keys=False,
                          default_flow_style=None)
    return head + "# a ThermoValve valve file (docs/reference.md); use it as gym.make(id, config=THIS_FILE)\n" + body


def write_valve(outs: OutputSet, path: PathLike, params: Mapping[str, float],
                effects: Mapping[str, Mapping[str, float]] | Effects | None = None, valve: ValveParams | None = None,
                source: str = "") -> Path:
    """Stage the valve file at ``path`` in ``outs`` (already :meth:`OutputSet.add`-ed: the caller
    declares its outputs up front and commits them together)."""
    return outs.write_text(path, valve_text(params, effects, valve, source))


def read_valve(path: PathLike) -> tuple[ValveParams, Effects]:
    """The valve and its effects from a valve file; ConfigError with one line naming the file and the
    problem (not a file, not YAML, no ``valve:`` mapping, an unknown field or effect, a bad value)."""
    cfg = load_valve_config(path)
    return cfg.valve, cfg.effects


def load_valve_config(path: PathLike) -> EnvConfig:
    """The environment config of a valve file (the defaults with its valve), checked as
    :func:`read_valve` does."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"valve file {str(p)!r} does not exist")
    try:
        data = yaml.safe_load(p.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise ConfigError(f"valve file {str(p)!r} is not valid YAML: {' '.join(str(exc).split())}") from None
    if not isinstance(data, Mapping) or not isinstance(data.get("valve"), Mapping):
        raise ConfigError(f"valve file {str(p)!r} must hold a 'valve:' mapping")
    try:
        return make_config(str(p))
    except ConfigError as exc:
        msg = str(exc)
        raise ConfigError(msg if str(p) in msg else f"valve file {str(p)!r}: {msg}") from None


__all__ = ["BASE_FIELDS", "valve_mapping", "valve_text", "write_valve", "read_valve", "load_valve_config"]
