"""One scenario registry: every static scenario NAME of valve_env.evaluation.scenarios has the
packaged file valve_env/data/scenarios/NAME.yaml giving the same environment, and no other file exists
there; the names a user writes (``"NAME"``, ``configs/scenarios/NAME.yaml``) load that file."""

from __future__ import annotations

from pathlib import Path

import pytest

from valve_env.config import make_config
from valve_env.data import packaged_scenario, scenario_files
from valve_env.evaluation.scenarios import LEADERBOARD_SCENARIOS, SCENARIOS, STATIC_SCENARIOS, episode_env_kwargs

REPO = Path(__file__).resolve().parents[2]


def test_registry_and_config_files_agree() -> None:
    files = scenario_files()
    assert sorted(files) == sorted(STATIC_SCENARIOS)
    for name in STATIC_SCENARIOS:
        assert make_config(files[name]) == make_config(**episode_env_kwargs(name, 0)), name


@pytest.mark.parametrize("spelling",
                         ["{name}", "configs/scenarios/{name}.yaml", "{repo}/configs/scenarios/{name}.yaml"])
def test_a_scenario_name_or_its_former_path_loads_the_packaged_file(spelling: str, tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """README's ``config="configs/scenarios/cold_supply.yaml"`` from a clone (and from any directory), and
    the bare name, give the packaged scenario; the repository keeps no copy."""
    monkeypatch.chdir(tmp_path)
    assert not (REPO / "configs" / "scenarios").exists()
    for name in STATIC_SCENARIOS:
        given = spelling.format(name=name, repo=REPO)
        assert packaged_scenario(given) is not None, given
        assert make_config(given) == make_config(**episode_env_kwargs(name, 0)), given


def test_a_path_that_names_a_file_loads_that_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A user's own configs/scenarios/cold_supply.yaml wins over the packaged one; an unknown name is one
    line listing the packaged names."""
    monkeypatch.chdir(tmp_path)
    own = tmp_path / "configs" / "scenarios" / "cold_supply.yaml"
    own.parent.mkdir(parents=True)
    own.write_text("scenario: {supply_C: 50.0}\n")
    assert packaged_scenario("configs/scenarios/cold_supply.yaml") is None
    assert make_config("configs/scenarios/cold_supply.yaml").scenario.supply_C == 50.0
    (tmp_path / "cold_supply").write_text("scenario: {supply_C: 51.0}\n")
    assert make_config("cold_supply").scenario.supply_C == 51.0
    with pytest.raises(ValueError, match="neither a file nor a packaged scenario; packaged: cold_supply, default"):
        make_config("cold_suply")
    with pytest.raises(ValueError, match="does not exist"):
        make_config("other/cold_supply.yaml")


def test_names_are_unique_and_mean_one_thing() -> None:
    assert len(set(SCENARIOS)) == len(SCENARIOS)
    assert set(LEADERBOARD_SCENARIOS) <= set(SCENARIOS)
    cfgs = {n: make_config(**episode_env_kwargs(n, 0)) for n in STATIC_SCENARIOS}
    names = list(cfgs)
    for i, a in enumerate(names):  # no two names for one environment either
        for b in names[i + 1:]:
            assert cfgs[a] != cfgs[b], (a, b)
    assert cfgs["cold_supply"].scenario.supply_C == 60.0 and cfgs["supply_65C"].scenario.supply_C == 65.0
