"""Benchmark tasks: a physical configuration (an EnvConfig from cited
parameters), a scenario, a reward, extra KPIs and an observation spec, on top
of the one plant model (valve_env.simulator). docs/tasks.md.

A :class:`Task` is data: the sections of its EnvConfig, the mode (what the
agent sets), its task layer (:mod:`valve_env.tasks.layers`: reward terms,
KPIs, observations) and the sources of its parameters. ``import valve_env``
registers every task id with Gymnasium (single env:
:class:`valve_env.tasks.env.ThermoValveTaskEnv`; batched:
:class:`valve_env.tasks.env.ThermoValveTaskVectorEnv`). The three original
ids are tasks too, with the identity layer and their own env classes,
unchanged.

    thermovalve tasks            # one line each: id, what makes it hard, action space
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from valve_env.config import EnvConfig, layer_config, load_yaml, make_config
from valve_env.params import ConfigError


@dataclass(frozen=True)
class Task:
    """A benchmark task (see the module docstring).

    ``sections`` are EnvConfig sections as mappings (as ``gym.make``'s
    keyword arguments); ``layer`` names the task layer and ``layer_params``
    its parameters; ``sources`` maps each parameter the task sets to its
    source; ``env_class`` is the name of its single-env class in
    :mod:`valve_env.tasks.env` (its docstring is the spec sheet).
    """

    id: str
    mode: str
    hard: str
    sections: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    layer: str | None = None
    layer_params: Mapping[str, Any] = field(default_factory=dict)
    sources: Mapping[str, str] = field(default_factory=dict)
    env_class: str | None = None
    superseded_by: str | None = None

    @property
    def is_original(self) -> bool:
        """One of the three ids of docs/reference.md, section 5 (its own env classes, no task layer)."""
        return self.env_class is None

    def config(self, config: str | Path | EnvConfig | Mapping[str, Any] | None = None, **overrides: Any) -> EnvConfig:
        """The task's EnvConfig, then a YAML file or mapping of sections, then keyword overrides
        (as ``gym.make``). An EnvConfig replaces the task's physical configuration.

        The valve's named effects combine by name (docs/tasks.md, "A valve file on a task"): the
        task's own effects stay, a file's (e.g. a valve file of ``thermovalve diagnose
        --valve-out``) and the keywords' are added, an effect named by both takes the later
        parameters (a file that overrides one of the task's own warns,
        :class:`~valve_env.config.EffectOverrideWarning`), and ``{name: null}`` removes one."""
        if isinstance(config, EnvConfig):
            base = config
        else:
            base = make_config(None, **{k: dict(v) for k, v in self.sections.items()})
            if config is not None:
                if isinstance(config, (str, Path)):
                    is_file, sections = True, load_yaml(config)
                else:
                    is_file, sections = False, dict(config)
                try:
                    base = layer_config(base, sections, owner=f"task {self.id}",
                                        source=f"config file {str(config)!r}" if is_file else "the config mapping")
                except ConfigError as exc:  # name the file, as make_config does for the original ids
                    if is_file and str(config) not in str(exc):
                        raise ConfigError(f"config file {str(config)!r}: {exc}") from None
                    raise
        return layer_config(base, overrides, owner=f"task {self.id}" if not isinstance(config, EnvConfig)
                            else "the configuration")

    def action_space_text(self) -> str:
        return {
            "setting": "Box(1): valve setting, degC [40, 80]",
            "pressure": "Box(1): pump differential pressure, mbar [0, 300]",
            "dual": "Box(2): [setting degC, pump dp mbar]",
        }[self.mode]


_SMALL: dict[str, Mapping[str, Any]] = {
    "tank": {"volume_l": 50.0, "UA_loss": 0.9},
    "scenario": {"tapping_profile": "L"},
}
#: a loop in continuous operation: the day starts with the tank at its target, not from a cold
#: tank (docs/tasks.md, "Steady start")
_STEADY_START = {"T_init_C": 60.0, "T_init_spread_K": 0.5}
_DH: dict[str, Mapping[str, Any]] = {
    "scenario": {
        **_STEADY_START,
        "supply_profile": "network", "supply_C": 75.0, "supply_amplitude_K": 5.0, "supply_noise_K": 1.5,
        "supply_tau_h": 1.0,
        "dp_profile": "network", "dp_mbar": 150.0, "dp_swing": 0.5, "dp_noise_mbar": 15.0, "dp_tau_s": 600.0,
    },
    "control": {"w_energy": 0.0, "w_track": 0.004},
}
#: the district-heating tasks' version 1: the store behind a thermostatic mixing valve, free from the 60 degC
#: target to 65 degC (docs/tasks.md, "ThermoValveDistrictHeating-v1")
_DH_V1: dict[str, Mapping[str, Any]] = {**_DH, "control": {**_DH["control"], "free_band_K": 5.0}}
#: the sources of what version 1 adds
_MIXING_VALVE_SOURCES: dict[str, str] = {
    "control.free_band_K = 5 (no tracking charge from 60 to 65 degC)":
        "a store behind an inline hot-water tempering (thermostatic mixing) valve at its outlet, EN 15092:2008 "
        "(Building valves - Inline hot water supply tempering valves): fitted to storage water heaters, it "
        "delivers a preset 45-65 degC from hot water up to 90 degC, so a store hotter than the 60 degC target is "
        "not an error at the tap; the store kept at 60 degC or more against legionella (ESGLI 2017, European "
        "Technical Guidelines for the Prevention, Control and Investigation of Infections Caused by Legionella "
        "species: stored at 60 degC, at least 50 degC at the outlets within a minute; DVGW W 551 (2004): 60 "
        "degC at the cylinder's outlet); 65 degC, the band's top, is the upper end of the usual 60-65 degC store "
        "setting, a conservative choice (the valve takes up to 90 degC; a screening found the same headroom "
        "with no upper end, docs/tasks.md)",
    "the tracking charge below 60 degC (unchanged)":
        "a mixing valve cannot heat: a store below the target delivers it too cold",
}

_STICKY: dict[str, Mapping[str, Any]] = {
    "valve": {"effects": {"stiction": {"band_mm": 0.1}}},
    "scenario": _STEADY_START,
    "control": {"w_energy": 0.0},
}

#: a hot-water circulation loop on the sticky task's tank (docs/tasks.md, "ThermoValveStickyCirculation-v0"): 80 m of
#: insulated loop at 0.2 W/(m K) (UA 16 W/K), its pump sized for a drop under 5 K (110 kg/h), the return at
#: mid-height, above the coil
_CIRCULATION = {"circ_kgh": 110.0, "circ_UA": 16.0, "circ_height": 0.5}
_STICKY_CIRCULATION: dict[str, Mapping[str, Any]] = {**_STICKY, "tank": _CIRCULATION}

TASKS: dict[str, Task] = {
    "ThermoValve-v0": Task(
        "ThermoValve-v0", "setting",
        "the original tank loop (docs/reference.md s. 5): a PI holds the outlet within 0.1 K after the first hour",
    ),
    "ThermoValvePressure-v0": Task(
        "ThermoValvePressure-v0", "pressure", "the original tank loop, acting through a variable-speed pump's dp",
    ),
    "ThermoValveDual-v0": Task(
        "ThermoValveDual-v0", "dual", "the original tank loop, acting on both the setting and the pump's dp",
    ),
    "ThermoValveStickyValve-v0": Task(
        "ThermoValveStickyValve-v0", "setting",
        "an aged valve whose stem sticks (band 0.1 mm = 5 % of stroke): a PI limit-cycles, the stem wears",
        sections=_STICKY,
        sources={
            "valve.effects.stiction.band_mm = 0.1 (jump_mm = band)":
                "5 % of the 2 mm stroke, the upper end of the 0.5-5 % of travel reported for industrial valves "
                "(Choudhury, Thornhill and Shah 2005, Control Eng. Practice 13:641-658; Jelali and Huang 2010, "
                "Detection and Diagnosis of Stiction in Control Loops, Springer)",
            "scenario.T_init_C = 60, T_init_spread_K = 0.5":
                "steady operation: the tank held at its 60 degC target (docs/reference.md, section 5) around "
                "the clock, so the day starts there, not from a cold tank (docs/tasks.md)",
            "control.w_energy = 0":
                "the heat is what the draws and standing losses need, the same for every controller that "
                "holds the target (reported as heat_kWh); the reward prices what the stem spoils (docs/tasks.md)",
            "everything else": "ThermoValve-v0's defaults (docs/reference.md, section 5, paper Tables 2-4)",
        },
        env_class="ThermoValveStickyValveEnv",
    ),
    "ThermoValveStickyCirculation-v0": Task(
        "ThermoValveStickyCirculation-v0", "setting",
        "StickyValve-v0 plus a hot-water circulation loop (about 0.6 kW of pipe loss): the sticky stem "
        "works mid-stroke, as in the stiction literature's loops",
        sections=_STICKY_CIRCULATION,
        sources={
            "everything of ThermoValveStickyValve-v0": "its sources (above; docs/tasks.md)",
            "a circulation loop at all":
                "DVGW W 551 (2004) and CEN/TR 16355 (2012): circulation keeps the hot-water pipes at 55 degC or "
                "more, the cylinder's outlet at 60 degC, the drop round the loop at most 5 K (required in "
                "'large' installations, > 400 l or > 3 l in a pipe run)",
            "tank.circ_UA = 16 W/K (80 m at 0.2 W/(m K))":
                "Hamburg, Mikola, Parts and Kalamees (2021), Energies 14(20) 6446: measured circulation losses of "
                "5.1 W/m (shafts) to 10.8 W/m (basements) with 40 mm pipe insulation, 0.14-0.29 W/(m K) at "
                "the loop's 57 degC against 20 degC; 80 m is the basement run and risers of a small "
                "apartment building (docs/tasks.md)",
            "tank.circ_kgh = 110":
                "the pump sized for W 551's drop of at most 5 K at the loop's loss (0.6 kW / (cp 5 K) = "
                "105 kg/h); the return comes back at 55.3 degC from the 60 degC outlet",
            "tank.circ_height = 0.5":
                "an assumption: the circulation return's connection at mid-height, above the coil (the "
                "connection's height differs between makes)",
        },
        env_class="ThermoValveStickyCirculationEnv",
    ),
    "ThermoValveSmallCylinder-v0": Task(
        "ThermoValveSmallCylinder-v0", "setting",
        "50 l cylinder under tapping cycle L: draws empty it, so the bulb lag and friction band reach the outlet",
        sections=_SMALL,
        sources={
            "tank.volume_l = 50": "the seed paper's 'small hot water cylinders' (30-80 l), docs/tasks.md",
            "tank.UA_loss = 0.9 W/K": "40 W at 45 K, the class B limit for 50 l (S < 12 + 5.93 V^0.4 W) of the "
                                      "standing-loss classes of Regulation (EU) 812/2013 (the 200 l default, "
                                      "86 W, sits at its class C limit)",
            "scenario.tapping_profile = L": "Regulation (EU) 814/2013 Annex III, cycle L (11.655 kWh/day, "
                                            "a 10 l/min bath draw)",
        },
        env_class="ThermoValveSmallCylinderEnv",
    ),
    "ThermoValveDistrictHeating-v0": Task(
        "ThermoValveDistrictHeating-v0", "setting",
        "swinging network supply and dp, a peak-load heat price and a return-temperature tariff: "
        "when and how the valve opens costs money",
        sections=_DH,
        layer="district_heating",
        layer_params={},
        sources={
            "scenario.supply_C = 75, supply_amplitude_K = 5, supply_noise_K = 1.5":
                "Danish/Swedish winter supply 70-90 degC with daily swings (Frederiksen and Werner, "
                "District Heating and Cooling, 2013; IEA DHC Annex IV project 06), docs/tasks.md",
            "scenario.dp_mbar = 150, dp_swing = 0.5, dp_noise_mbar = 15":
                "dp at a consumer substation falls with the network load (the pressure diagram of a "
                "network, Frederiksen and Werner 2013), docs/tasks.md",
            "network_load": "Gadd and Werner (2013), Applied Energy 106: daily heat-load variations",
            "tariff": "REFA Energi Holeby / Lemvig Varmevaerk motivation tariffs (1 % of the MWh price per K), "
                      "peak-load price after Song, Wallin and Li (2017), Applied Energy 194",
            "scenario.T_init_C = 60, T_init_spread_K = 0.5":
                "steady operation: the tank held at its 60 degC target (docs/reference.md, section 5)",
            "storage settlement at 80 EUR/MWh":
                "the change of the stored heat valued at the tariff's mean price: the next day recharges "
                "a tank left colder (docs/tasks.md)",
        },
        env_class="ThermoValveDistrictHeatingEnv",
        superseded_by="ThermoValveDistrictHeating-v1",
    ),
    "ThermoValveDistrictHeatingPower-v0": Task(
        "ThermoValveDistrictHeatingPower-v0", "setting",
        "DistrictHeating-v0's network and bill plus a power charge on the day's highest hourly mean power: "
        "recharging the tank at full flow after a draw sets the peak",
        sections=_DH,
        layer="district_heating_power",
        layer_params={},
        sources={
            "everything of ThermoValveDistrictHeating-v0": "its sources (above; docs/tasks.md)",
            "power charge basis: the highest hourly mean power":
                "SEVAB Strängnäs Energi, district-heating Prislista 2 (sevab.com, Fjärrvärmepris): the billed "
                "power is the mean of the five highest hourly powers metered in the previous winter; peak-load "
                "components in Swedish price models: Song, Wallin and Li (2017), Applied Energy 194; Sernhed, "
                "Gåverud and Sandgren (2017), Int. J. Sustainable Energy Planning and Management 13",
            "power_eur_kW_day = 0.192":
                "a year's power charge per kW against the winter energy price, median of 7 Swedish utilities "
                "(0.876 MWh per kW-year, Lidköping Energi 2025; range 0.61 Halmstad Energi och Miljö to 2.28 "
                "Bodens Energi 2024), at the task's 80 EUR/MWh: 70.1 EUR/kW-year, a 365th of it per day "
                "(docs/tasks.md)",
        },
        env_class="ThermoValveDistrictHeatingPowerEnv",
        superseded_by="ThermoValveDistrictHeatingPower-v1",
    ),
    "ThermoValveDistrictHeating-v1": Task(
        "ThermoValveDistrictHeating-v1", "setting",
        "DistrictHeating-v0 with the store behind a thermostatic mixing valve: a top held at 60-65 degC "
        "costs no tracking, so charging the tank in the cheap hours pays",
        sections=_DH_V1,
        layer="district_heating",
        layer_params={},
        sources={"everything of ThermoValveDistrictHeating-v0": "its sources (above; docs/tasks.md)",
                 **_MIXING_VALVE_SOURCES},
        env_class="ThermoValveDistrictHeatingV1Env",
    ),
    "ThermoValveDistrictHeatingPower-v1": Task(
        "ThermoValveDistrictHeatingPower-v1", "setting",
        "DistrictHeatingPower-v0 with the store behind a thermostatic mixing valve (free from 60 to 65 degC)",
        sections=_DH_V1,
        layer="district_heating_power",
        layer_params={},
        sources={"everything of ThermoValveDistrictHeatingPower-v0": "its sources (above; docs/tasks.md)",
                 **_MIXING_VALVE_SOURCES},
        env_class="ThermoValveDistrictHeatingPowerV1Env",
    ),
}

#: every task id registered besides the original three (superseded versions included: kept registered and
#: bit for bit for reproducibility, as Gymnasium practice keeps an old version)
TASK_IDS: tuple[str, ...] = tuple(t for t, task in TASKS.items() if not task.is_original)
#: the current benchmark tasks, in the order `thermovalve tasks` lists them and `thermovalve benchmark` runs
#: them by default: TASK_IDS without the versions a later one supersedes (docs/tasks.md, "Versions")
CURRENT_TASK_IDS: tuple[str, ...] = tuple(t for t in TASK_IDS if TASKS[t].superseded_by is None)


def get_task(task_id: str) -> Task:
    """The task registered as ``task_id``; ValueError naming the known ids otherwise."""
    try:
        return TASKS[task_id]
    except KeyError:
        raise ValueError(f"unknown task id {task_id!r}; known: {', '.join(TASKS)}") from None


def task_config(task_id: str, config: Any = None, **overrides: Any) -> EnvConfig:
    """The EnvConfig of ``task_id`` with ``config`` and keyword overrides applied (as ``gym.make``)."""
    overrides.pop("max_episode_steps", None)
    overrides.pop("render_mode", None)
    overrides.pop("tariff", None)
    return get_task(task_id).config(config, **overrides)


def register_tasks(max_episode_steps: int) -> None:
    """Register the task ids (not the original three) with Gymnasium."""
    from gymnasium.envs.registration import register, registry

    for task_id in TASK_IDS:
        if task_id in registry:
            continue
        cls = TASKS[task_id].env_class
        register(
            id=task_id,
            entry_point="valve_env.tasks.env:make_task_env",
            vector_entry_point=f"valve_env.tasks.env:{str(cls).removesuffix('Env')}VectorEnv",
            max_episode_steps=max_episode_steps,
            kwargs={"task_id": task_id},
        )


__all__ = ["CURRENT_TASK_IDS", "TASKS", "TASK_IDS", "Task", "get_task", "register_tasks", "task_config"]
