"""The RL add-on plugs into the core through entry points (valve_env.plugins): its controller loader
and its commands are declared in pyproject.toml, the core imports no ``agents`` module, and without
the ``rl`` extra ``make_controller("ppo")`` says in one line which extra to install.

The entry points of the installed distribution are read when it is installed; these tests build
them from pyproject.toml, so they hold what the next install registers (tests/test_wheel.py reads
them from a real install)."""

from __future__ import annotations

import sys
import tomllib
from importlib.metadata import EntryPoint
from pathlib import Path

import pytest

import valve_env.cli as cli
import valve_env.controllers as controllers
from valve_env.controllers import PIController, UnknownControllerError, make_controller
from valve_env.plugins import CLI_GROUP, CONTROLLERS_GROUP, NotProvided, missing_extra

PYPROJECT = Path(__file__).resolve().parents[1] / "pyproject.toml"


def declared(group: str) -> list[EntryPoint]:
    """The entry points of ``group`` that pyproject.toml declares."""
    table = tomllib.loads(PYPROJECT.read_text())["project"]["entry-points"][group]
    return [EntryPoint(name, value, group) for name, value in sorted(table.items())]


def test_pyproject_registers_the_agents_loader_and_commands() -> None:
    assert [(ep.name, ep.value) for ep in declared(CONTROLLERS_GROUP)] == [("agents", "agents.loader:load_agent")]
    assert [(ep.name, ep.value) for ep in declared(CLI_GROUP)] == [("agents", "agents.cli")]
    assert not any(m.startswith("agents") for m in cli.SUBCOMMAND_MODULES)


def test_the_cli_takes_its_plugins_commands_from_the_entry_points(monkeypatch: pytest.MonkeyPatch) -> None:
    def commands() -> set[str]:
        parser = cli.build_parser()
        sub = next(a for a in parser._actions if a.dest == "command")
        return set(sub.choices)  # type: ignore[arg-type]

    monkeypatch.setattr(cli, "plugins", lambda group: declared(group) if group == CLI_GROUP else [])
    with_agents = commands()
    assert {"train", "leaderboard", "sweep", "benchmark", "task-leaderboard", "curves"} <= with_agents
    monkeypatch.setattr(cli, "plugins", lambda group: [])
    core = commands()
    assert {"demo", "evaluate", "fit", "diagnose", "experiment", "tune", "bench"} <= core
    assert not core & {"train", "leaderboard", "sweep", "curves"}


def test_without_a_plugin_an_agent_name_is_one_line_naming_the_extra(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(controllers, "plugins", lambda group: [])
    with pytest.raises(UnknownControllerError) as info:
        make_controller("ppo")
    msg = str(info.value)
    assert "\n" not in msg and "'ppo'" in msg and "self_acting, pi, pi_compensated" in msg
    assert "no controller plug-in is installed" in msg and "pip install 'thermovalve[rl]'" in msg
    assert isinstance(make_controller("pi"), PIController)  # the built-ins need no plug-in


@pytest.mark.parametrize("missing", ["stable_baselines3", "torch"])
def test_without_the_rl_extra_ppo_names_the_extra_in_one_line(missing: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """The agents plug-in is installed with the core (it is in the wheel) but its extra is not: loading the
    plug-in fails on the missing module, and make_controller names the extra."""
    import agents

    monkeypatch.setattr(controllers, "plugins", declared)
    for attr in [a for a in ("cem", "loader", "train", "wrappers") if hasattr(agents, a)]:
        monkeypatch.setattr(agents, attr, getattr(agents, attr))  # the package's attributes come back too
    for mod in [m for m in sys.modules if m == missing or m.startswith(missing + ".") or m.startswith("agents.")]:
        monkeypatch.delitem(sys.modules, mod)
    monkeypatch.setitem(sys.modules, missing, None)  # import <missing> -> ImportError
    if missing == "torch":  # stable_baselines3 imports torch; without it sb3 cannot be imported either
        for mod in [m for m in sys.modules if m.startswith("stable_baselines3")]:
            monkeypatch.delitem(sys.modules, mod)
    with pytest.raises(UnknownControllerError) as info:
        make_controller("ppo", "ThermoValve-v0")
    msg = str(info.value)
    assert "\n" not in msg and msg.startswith("unknown controller 'ppo': not a built-in (self_acting, pi,")
    assert "install the 'rl' extra with pip install 'thermovalve[rl]'" in msg, msg


def test_a_loader_that_does_not_provide_the_name_passes_to_the_next(monkeypatch: pytest.MonkeyPatch) -> None:
    """Loaders are asked in turn; NotProvided from one moves on, and the error lists every loader's answer."""
    calls: list[str] = []

    class Fake:
        def __init__(self, name: str, provides: str) -> None:
            self.name, self.value, self.provides = name, f"fake:{name}", provides

        def load(self) -> object:
            def loader(name: str, env_id: str, **kwargs: object) -> object:
                calls.append(self.name)
                if name != self.provides:
                    raise NotProvided(f"{self.name} has no {name!r}")
                return (self.name, name, env_id, kwargs)
            return loader

    monkeypatch.setattr(controllers, "plugins", lambda group: [Fake("a", "x"), Fake("b", "y")])
    assert make_controller("y", "ThermoValvePressure-v0", k=1) == ("b", "y", "ThermoValvePressure-v0", {"k": 1})
    assert calls == ["a", "b"]
    with pytest.raises(UnknownControllerError, match="a has no 'z'; b has no 'z'"):
        make_controller("z")


def test_missing_extra_names_only_optional_modules() -> None:
    assert missing_extra(ModuleNotFoundError("no", name="dask.distributed")) is not None
    assert missing_extra(ModuleNotFoundError("no", name="numpy")) is None
