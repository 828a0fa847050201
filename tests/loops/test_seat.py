"""The valve's seat in the loop model (docs/loops.md, "Loops from the environment"): below its seat a
valve passes nothing whatever its input, and a sticky stem resting on the seat breaks away only once the OP has
risen the slip jump above it (the stick-slip's lower end stop)."""

from __future__ import annotations

import math

import numpy as np

from valve_env.loops.model import seated, valve_path
from valve_env.physics import stickslip


def test_seat_is_the_stick_slips_end_stop() -> None:
    rng = np.random.default_rng(3)
    op = 50 + np.cumsum(rng.normal(0, 0.4, 500))
    seat = float(np.quantile(op, 0.4))
    # the linear valve: clipped at the seat; no seat: the record itself
    np.testing.assert_array_equal(valve_path(op, 0.0, 0.0, seat=seat), np.maximum(op, seat))
    np.testing.assert_array_equal(valve_path(op, 0.0, 0.0), op)
    assert seated(op, -math.inf) is op
    # a sticky valve: the project's stick-slip with its lower end stop at the seat
    for S, J in ((1.5, 1.5), (1.5, 0.0)):
        np.testing.assert_array_equal(valve_path(op, S, J, seat=seat), stickslip.simulate(op, S, J, lo=seat))
        assert valve_path(op, S, J, seat=seat).min() >= seat


def test_stem_on_its_seat_breaks_away_after_the_jump() -> None:
    """OP falls below the seat, then rises: the stem stays on the seat until OP is J above it, then jumps to OP."""
    op = np.concatenate([np.linspace(52.0, 48.0, 41), np.linspace(48.0, 53.0, 51)])
    x = valve_path(op, 1.0, 1.0, seat=50.0)
    up = op[41:]
    moved = x[41:] > 50.0 + 1e-9
    first = int(np.argmax(moved))
    assert up[first] > 51.0 - 1e-9 and up[first - 1] <= 51.0 + 1e-9
    assert x[41 + first] == up[first]
