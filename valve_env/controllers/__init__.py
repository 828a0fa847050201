"""Controllers for the ThermoValve environments, all with stable-baselines3's
``predict(observation, state, episode_start, deterministic)``.

Built-in baselines (see docs/baselines.md):

* ``self_acting``: the valve alone at a fixed setting (today's practice);
* ``pi``: a discrete PI on the outlet temperature with anti-windup and a
  bumpless start, SIMC-tuned on a simulator step test
  (:mod:`valve_env.controllers.tuning`, gains in ``valve_env/data/controllers.yaml``);
* ``pi_compensated``: the PI plus an inverse-model Dahl hysteresis compensator;
* ``knocker``, ``constant_reinforcement``, ``two_move``, ``two_move_position``,
  ``pi_integral_band``: stiction compensators from the literature on the PI's setting, and
  ``pi_wear``: an event-based PI that spares the stem (:mod:`valve_env.controllers.compensators`,
  docs/controllers.md); ``pi_stiction_tuned``: a PI whose gains compensate stiction by tuning, from a
  describing-function analysis (Mohammad & Huang 2012; :mod:`valve_env.controllers.stiction_tuning`);
* ``oracle``: MPC with the true plant and perfect preview, the bound on what
  is achievable (:mod:`valve_env.controllers.oracle`; it must be bound to the
  envs it controls, which the evaluator does).

``make_controller(name, env_id)`` builds one; any other name (``ppo``,
``sac``, ...) goes to the controller loaders that plug-ins register (the ``thermovalve.controllers``
entry points, :mod:`valve_env.plugins`; the RL add-on registers ``agents.loader.load_agent``), and a
name that is a path (it holds a ``/``, or starts with ``.`` or ``~``: e.g. ``out/runs/tiny_ppo``,
``./tiny_ppo``) goes to them with ``run_dir=path``: the run directory a ``thermovalve train`` run
writes (:func:`run_dir_of`).
"""

from __future__ import annotations

import dataclasses
import inspect
import math
import numbers
import os
from pathlib import Path
from typing import Any

from valve_env.controllers.base import ALL_ENV_MODES, Controller, PredictPolicy, original_id
from valve_env.controllers.baselines import DahlCompensator, PICompensated, PIController, SelfActing
from valve_env.controllers.compensators import (
    ConstantReinforcement,
    Knocker,
    PIIntegralBand,
    PIWear,
    TwoMove,
    TwoMovePosition,
)
from valve_env.controllers.oracle import Oracle, OracleSettings
from valve_env.controllers.stiction_tuning import PIStictionTuned
from valve_env.plugins import CONTROLLERS_GROUP, NotProvided, missing_extra, plugins

BASELINES: dict[str, type[Controller]] = {
    SelfActing.name: SelfActing,
    PIController.name: PIController,
    PICompensated.name: PICompensated,
    PIWear.name: PIWear,
    Knocker.name: Knocker,
    ConstantReinforcement.name: ConstantReinforcement,
    TwoMove.name: TwoMove,
    TwoMovePosition.name: TwoMovePosition,
    PIIntegralBand.name: PIIntegralBand,
    PIStictionTuned.name: PIStictionTuned,
}
"""Controllers that read only the observation (the default set of ``thermovalve evaluate``)."""
ORACLES: dict[str, type[Controller]] = {Oracle.name: Oracle}
"""Controllers that read the true plant (bound to their envs by the evaluator; not a default: slow)."""
CONTROLLERS: dict[str, type[Controller]] = {**BASELINES, **ORACLES}


class UnknownControllerError(ValueError):
    """A controller name that is neither a baseline nor a loadable agent."""


def controller_options(name: str) -> dict[str, str]:
    """The options of built-in controller ``name`` (its constructor's keywords, through the ``**kwargs``
    it forwards to its bases; the oracle's :class:`OracleSettings`), each with its type annotation."""
    opts: dict[str, str] = {}
    for klass in CONTROLLERS[name].__mro__:
        init = klass.__dict__.get("__init__")
        if init is None or klass is object:
            continue
        params = inspect.signature(init).parameters.values()
        for p in params:
            if p.name not in ("self", "env_id") and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD):
                opts.setdefault(p.name, str(p.annotation))
        if klass is Oracle:
            opts.update({f.name: str(f.type) for f in dataclasses.fields(OracleSettings)})
            break
        if not any(p.kind is p.VAR_KEYWORD for p in params):
            break
    return opts


def check_options(name: str, options: dict[str, Any]) -> None:
    """Raise ValueError naming the option unless every one of ``options`` is an option of built-in
    controller ``name`` and each numeric option is a finite number (an integer where it must be), so a
    command line's ``name:key=value`` fails with one line that names it. Ranges are the constructors'."""
    known = controller_options(name)
    unknown = sorted(set(options) - set(known))
    if unknown:
        raise UnknownControllerError(f"controller {name!r} has no option(s) {unknown}; its options: "
                                     f"{', '.join(known)}")
    for key, value in options.items():
        kind = known[key].split("|")[0].strip()
        if kind not in ("float", "int") or (value is None and "None" in known[key]):
            continue
        ok = isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value)
        if not ok or (kind == "int" and value != int(value)):
            what = "an integer" if kind == "int" else "a finite number"
            raise ValueError(f"controller {name!r} option {key} must be {what}, got {value!r}")


#: the files that make a directory a training run (agents/train.py writes them; ``model.zip`` or
#: ``best/best_model.zip`` holds the policy)
RUN_FILES = ("config.yml",)
RUN_MODELS = ("best/best_model.zip", "model.zip")


def is_path_name(name: str) -> bool:
    """Whether controller ``name`` names a path (a trained run directory) rather than a controller:
    it holds a path separator or starts with ``.`` or ``~``. A bare name (``ppo``) never does, even
    where a directory of that name exists."""
    return "/" in name or os.sep in name or name.startswith((".", "~"))


def run_dir_of(name: str) -> Path:
    """The training run directory that path-like controller ``name`` names, checked: it exists and
    holds ``config.yml`` and a model (``best/best_model.zip`` or ``model.zip``); else an
    :class:`UnknownControllerError` in one line naming what is missing."""
    path = Path(name).expanduser()
    if not path.is_dir():
        what = "does not exist" if not path.exists() else "is not a directory"
        raise UnknownControllerError(f"controller {name!r} is a path that {what}; give a training run "
                                     "directory (what thermovalve train --out writes) or a controller name")
    missing = [f for f in RUN_FILES if not (path / f).is_file()]
    if not any((path / m).is_file() for m in RUN_MODELS):
        missing.append(" or ".join(RUN_MODELS))
    if missing:
        raise UnknownControllerError(f"controller {name!r} is not a training run directory: no "
                                     f"{', no '.join(missing)} in {path}")
    return path


def make_controller(name: str, env_id: str = "ThermoValve-v0", **kwargs: Any) -> PredictPolicy:
    """A controller by name for ``env_id``.

    Built-ins (:data:`CONTROLLERS`): ``self_acting``, ``pi``, ``pi_compensated``, ``pi_wear``,
    ``knocker``, ``constant_reinforcement``, ``two_move``, ``two_move_position``, ``pi_integral_band``,
    ``pi_stiction_tuned``, ``oracle``
    (keyword arguments go to their constructors). Any other name goes to each registered controller
    loader in turn (:mod:`valve_env.plugins`; trained agents: ``agents.loader.load_agent(name, env_id,
    **kwargs)``); a path (:func:`is_path_name`) is a training run directory, handed to the loaders as
    ``run_dir``. When none provides it, or a loader needs an extra that is not installed,
    :class:`UnknownControllerError` names the controller in one line (and the extra to install).
    """
    if env_id not in ALL_ENV_MODES:
        raise ValueError(f"unknown env id {env_id!r}; known: {list(ALL_ENV_MODES)}")
    if name in CONTROLLERS:
        check_options(name, kwargs)
        return CONTROLLERS[name](env_id, **kwargs)
    if is_path_name(name):
        kwargs = {**kwargs, "run_dir": run_dir_of(name)}
    notes: list[str] = []
    cause: BaseException | None = None
    for ep in plugins(CONTROLLERS_GROUP):
        try:
            loader = ep.load()
        except ImportError as exc:  # a plug-in whose extra is not installed
            notes.append(missing_extra(exc) or f"the controller plug-in {ep.value} could not be imported ({exc})")
            cause = exc
            continue
        try:
            return loader(name, env_id, **kwargs)
        except NotProvided as exc:
            notes.append(str(exc))
            cause = exc
    if not notes:
        notes.append("no controller plug-in is installed (trained agents: pip install 'thermovalve[rl]')")
    raise UnknownControllerError(
        f"unknown controller {name!r}: not a built-in ({', '.join(CONTROLLERS)}); {'; '.join(notes)}"
    ) from cause


__all__ = [
    "BASELINES",
    "CONTROLLERS",
    "ORACLES",
    "ConstantReinforcement",
    "Controller",
    "DahlCompensator",
    "Knocker",
    "Oracle",
    "OracleSettings",
    "PIIntegralBand",
    "PIStictionTuned",
    "PIWear",
    "TwoMove",
    "TwoMovePosition",
    "PICompensated",
    "PIController",
    "PredictPolicy",
    "RUN_FILES",
    "RUN_MODELS",
    "SelfActing",
    "UnknownControllerError",
    "check_options",
    "controller_options",
    "is_path_name",
    "make_controller",
    "original_id",
    "run_dir_of",
]
