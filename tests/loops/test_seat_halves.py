"""The seated fallback's halves (docs/loops.md, "Decision", condition 3): the held-out check
cuts the record in halves, and a half in which the fitted valve never crosses its band back holds no evidence of the
band; the seated fallback names only a band crossed back within each half."""

from __future__ import annotations

import numpy as np

from valve_env.loops.diagnose import (
    BAND_CANDIDATE,
    band_resolved,
    compare,
    crosses_back,
    crosses_back_in_halves,
    diagnose,
    heldout_halves,
    linear_seat_kept,
    select_noise_order,
)
from valve_env.loops.envloop import record_env_loop
from valve_env.loops.model import FitMemo, scan_seats


def test_heldout_halves_cover_the_record_after_each_cut() -> None:
    (a0, a1), (b0, b1) = heldout_halves(480, 14)
    assert (a0, a1, b0, b1) == (14, 240, 254, 480)


def test_seated_fallback_needs_the_band_crossed_back_in_each_half() -> None:
    """Smooth seat seed 364 (development): the seated comparison is justified with a stick-slip of 4.6 % of OP whose
    valve moves three times in 4 h, all in the second half, reversing once (so `band_resolved`
    holds); the held-out check then tests the valve on one half only. Without the halves' condition it was named."""
    loop = record_env_loop(0.0, seed=364)
    s = select_noise_order(loop)
    memo: FitMemo = {}
    unseated = compare(loop, s, memo=memo)
    assert not unseated.justified
    seats = linear_seat_kept(loop, s, scan_seats(loop.op, loop.pv, s), unseated.fits["linear"], memo)
    alt = compare(loop, s, seats=seats, memo=memo)
    fit = alt.fits[BAND_CANDIDATE]
    assert alt.justified and band_resolved(fit, loop.op)
    (a0, a1), (b0, b1) = heldout_halves(loop.n, s.k0)
    x = fit.path(loop.op)
    assert np.ptp(x[a0:a1]) < 1e-9 and crosses_back(x[b0:b1])  # held still through the first half
    assert not crosses_back_in_halves(fit, loop, s.k0)
    d = diagnose(loop)
    assert d.cause != "stiction" and d.result["decision"]["seat"]["seated"] is False


def test_sticky_seat_relay_crosses_back_in_both_halves() -> None:
    """Sticky seat seed 0 (development): the seated relay reverses tens of times in each half and stays named."""
    loop = record_env_loop(0.1, seed=0)
    d = diagnose(loop)
    assert d.cause == "stiction" and d.result["decision"]["seat"]["seated"] is True
    assert crosses_back_in_halves(d.fits[BAND_CANDIDATE], loop, d.settings.k0)
