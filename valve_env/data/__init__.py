"""The core's package data, read through :mod:`importlib.resources` so that it loads the same from a
wheel installed anywhere as from a clone (docs/architecture.md, "Package data"):

* ``ecodesign_tapping_profile_{S,M,L}.csv``: the EU tapping cycles (``PROFILES_SOURCE.md``);
* ``controllers.yaml``: the built-in controllers' stored gains and settings, keyed by env id
  (:mod:`valve_env.controllers.tuning`);
* ``scenarios/NAME.yaml``: the static named scenarios of :mod:`valve_env.evaluation.scenarios`, one
  file each.

A config given by name resolves to the packaged scenario file (:func:`packaged_scenario`): a bare name
(``config="cold_supply"``), and a path ending in ``configs/scenarios/NAME.yaml`` that names no file (the
files' former place in the repository, which user code and the docs still write). A path that names a
file always loads that file.
"""

from __future__ import annotations

from importlib import resources
from importlib.resources.abc import Traversable
from pathlib import Path, PurePath

PACKAGE = "valve_env.data"


def data_file(name: str) -> Traversable:
    """The packaged data file ``name`` (a path relative to this package, ``/``-separated)."""
    node = resources.files(PACKAGE)
    for part in name.split("/"):
        node = node / part
    return node


def scenario_files() -> dict[str, Traversable]:
    """The packaged scenario files by name (``scenarios/NAME.yaml``), sorted by name."""
    found = {f.name[: -len(".yaml")]: f for f in data_file("scenarios").iterdir()
             if f.is_file() and f.name.endswith(".yaml")}
    return dict(sorted(found.items()))


def packaged_scenario(config: str | PurePath) -> Traversable | None:
    """The packaged scenario file that ``config`` stands for, or None when it stands for none.

    Only a ``config`` that names no existing file resolves: a bare scenario name (no directory, no
    suffix: ``"cold_supply"``) or a path whose last parts are ``configs/scenarios/NAME.yaml``."""
    if Path(config).exists():
        return None
    p = PurePath(config)
    if len(p.parts) == 1 and not p.suffix:
        name = p.name
    elif p.suffix == ".yaml" and tuple(p.parts[-3:-1]) == ("configs", "scenarios"):
        name = p.stem
    else:
        return None
    return scenario_files().get(name)
