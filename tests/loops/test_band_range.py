"""A band the record resolves (docs/loops.md, "Twelfth session: a band wider than the OP's range"): from one sample's
OP move to the OP's whole range. A wider band can never be crossed back, so the valve only moves on in its first
direction and the record shows the slip jump, not the band; the seated fallback does not name such a band."""

from __future__ import annotations

import numpy as np

from valve_env.loops.diagnose import band_resolved, compare, diagnose, sampling_offset, select_noise_order
from valve_env.loops.envloop import record_env_loop
from valve_env.loops.model import scan_seats, valve_path


def test_a_band_wider_than_the_op_range_is_never_crossed_back() -> None:
    rng = np.random.default_rng(5)
    k = np.arange(800)
    op = 50 + 2.0 * np.sin(2 * np.pi * k / 150) * (1 + k / 800) + rng.normal(0, 0.1, k.size)  # a growing swing
    width = float(np.ptp(op))
    J = 0.05 * width
    for d0 in (1.0, -1.0):
        wide = valve_path(op, 1.2 * width, J, d0)
        wider = valve_path(op, 3.0 * width, J, d0)
        moves = np.diff(wide)[np.abs(np.diff(wide)) > 1e-12]
        assert moves.size > 0 and np.all(np.sign(moves) == d0)  # only on, in its first direction
        # every band beyond the range: the same path but for the resting offset (S - J) / 2
        np.testing.assert_allclose(wider - wide, -d0 * (3.0 - 1.2) * width / 2, atol=1e-9)
    # within the range the valve is pushed back through its band: it reverses
    inside = np.diff(valve_path(op, 0.3 * width, J))
    assert np.any(inside > 1e-12) and np.any(inside < -1e-12)


def test_band_resolved_from_one_samples_move_to_the_range() -> None:
    rng = np.random.default_rng(6)
    op = 50 + np.cumsum(rng.normal(0, 0.3, 500))
    lo, hi = sampling_offset(op), float(np.ptp(op))
    assert band_resolved(lo, op) and band_resolved(hi, op) and band_resolved(0.5 * (lo + hi), op)
    assert not band_resolved(0.9 * lo, op) and not band_resolved(1.01 * hi, op)


def test_seated_fallback_does_not_name_a_band_wider_than_the_op_range() -> None:
    """Smooth seat seed 8 (development): its seated comparison is justified with a stick-slip band wider than the OP's
    whole range (a valve that slips twice, in one direction, in 4 h), which named it until the twelfth session."""
    loop = record_env_loop(0.0, seed=8)
    s = select_noise_order(loop)
    memo: dict = {}
    alt = compare(loop, s, seats=scan_seats(loop.op, loop.pv, s), memo=memo)
    assert alt.justified and alt.fits["stiction"].S > np.ptp(loop.op)
    d = diagnose(loop)
    assert d.cause != "stiction" and d.result["decision"]["seat"]["seated"] is False
