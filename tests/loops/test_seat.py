"""The valve's seat in the loop model (docs/loops.md, "Loops from the environment"): below its seat a
valve passes nothing whatever its input, and a sticky stem resting on the seat breaks away only once the OP has
risen the slip jump above it (the stick-slip's lower end stop)."""

from __future__ import annotations

import math

import numpy as np
from scipy.signal import lfilter

from valve_env.loops.model import Settings, scan_seats, seated, valve_path
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


def _seated_loop(S: float, J: float, seat_q: float | None, seed: int) -> tuple[np.ndarray, np.ndarray, float]:
    """A first-order process (tau 5 samples, delay 1) behind a valve, under OP that is a slow random walk; white
    PV noise. Returns OP, PV and the seat (-inf for none)."""
    rng = np.random.default_rng(seed)
    n = 600
    op = 50 + np.cumsum(rng.normal(0, 0.3, n))
    seat = float(np.quantile(op, seat_q)) if seat_q is not None else -math.inf
    x = valve_path(op, S, J, seat=seat)
    a = math.exp(-1 / 5)
    w = lfilter([1 - a], [1, -a], np.concatenate([[x[0]], x[:-1]]), zi=[a * x[0]])[0]
    return op, 2.0 * w + rng.normal(0, 0.05, n), seat


def test_scan_finds_the_seat_and_only_where_there_is_one() -> None:
    s = Settings(dt=10.0, noise_order=0)
    op, pv, seat = _seated_loop(0.0, 0.0, 0.4, seed=1)
    found = scan_seats(op, pv, s)
    # within one step of the quantile grid, and gained far beyond a parameter's cost
    assert abs(np.mean(op <= found.linear) - np.mean(op <= seat)) <= 0.05 + 1e-9
    assert found.lr_linear > 10 * math.log(op.size)
    op, pv, _ = _seated_loop(0.0, 0.0, None, seed=2)
    none = scan_seats(op, pv, s)
    assert none.linear == -math.inf and none.nonlinear == -math.inf


def test_scan_finds_a_sticky_valve_on_its_seat() -> None:
    """The second stage finds a sticky valve's band and seat (the stem rests on its seat: a relay)."""
    s = Settings(dt=10.0, noise_order=0)
    op, pv, seat = _seated_loop(2.0, 2.0, 0.4, seed=4)
    found = scan_seats(op, pv, s)
    assert math.isfinite(found.nonlinear) and abs(found.nonlinear - seat) < 0.5
    assert abs(found.S - 2.0) < 0.3 * 2.0
    assert found.lr_nonlinear > found.lr_linear
