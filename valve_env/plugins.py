"""Plug-ins: what other code adds to the core through entry points, so the core imports none of it.

Two entry-point groups (``[project.entry-points."GROUP"]`` in a distribution's pyproject.toml, read with
:func:`importlib.metadata.entry_points`):

* ``thermovalve.controllers``: ``NAME = "module:loader"``; ``loader(name, env_id, **kwargs)`` returns a
  controller with ``predict(observation, state, episode_start, deterministic)`` for a controller name that
  is not a built-in, or raises :class:`NotProvided` when it has no controller of that name.
  :func:`valve_env.controllers.make_controller` asks each loader in turn.
* ``thermovalve.cli``: ``NAME = "module"``; the module's ``register(subparsers)`` adds its sub-commands
  to ``thermovalve`` (:mod:`valve_env.cli`).

The RL add-on (``agents/``, the ``rl`` extra) registers ``agents.loader:load_agent`` and ``agents.cli``
this way. A plug-in whose module needs an extra that is not installed fails to load with an ImportError;
:func:`missing_extra` turns that into the one line that names the extra. An editable install reads the
entry points when it is installed: after adding one, re-run ``pip install -e .``.
"""

from __future__ import annotations

from importlib.metadata import EntryPoint, entry_points

CONTROLLERS_GROUP = "thermovalve.controllers"
CLI_GROUP = "thermovalve.cli"

#: optional modules and the extra that provides them
EXTRAS: dict[str, str] = {"stable_baselines3": "rl", "torch": "rl", "sb3_contrib": "rl", "distributed": "rl",
                          "dask": "rl", "tensorboard": "rl"}


class NotProvided(LookupError):
    """A controller loader's answer for a name it has no controller of (the next loader is asked)."""


def plugins(group: str) -> list[EntryPoint]:
    """The entry points of ``group``, sorted by name (one per name: the first distribution on the path)."""
    found: dict[str, EntryPoint] = {}
    for ep in entry_points(group=group):
        found.setdefault(ep.name, ep)
    return [found[k] for k in sorted(found)]


def missing_extra(exc: ImportError) -> str | None:
    """The one-line advice when ``exc`` is a missing optional module (None for any other ImportError)."""
    name = (getattr(exc, "name", None) or "").split(".")[0]
    extra = EXTRAS.get(name)
    if extra is None:
        return None
    return (f"the optional package {name!r} is missing: install the {extra!r} extra with "
            f"pip install 'thermovalve[{extra}]' (from a clone: pip install -e '.[{extra}]')")
