"""Control-loop diagnosis from plant-historian data: valve stiction and its band (docs/loops.md)."""

from valve_env.loops.io import LoopData, LoopDataError, read_loop

__all__ = ["LoopData", "LoopDataError", "read_loop"]
