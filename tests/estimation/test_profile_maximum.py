"""The core's profile search (``valve_env.ident.mle.profile_maximum``): a grid, then Brent's bounded search between
the best grid point's neighbours; every evaluation is in the returned profile."""

from __future__ import annotations

import math

import numpy as np
import pytest

from valve_env.ident.mle import profile_maximum


def test_refines_between_the_best_points_neighbours() -> None:
    # a rugged profile: a narrow ridge at 2.3 on a slope that rises to the right, beyond the ridge's neighbours
    def f(x: float) -> float:
        return 0.1 * x + 3.0 * math.exp(-((x - 2.3) / 0.2) ** 2)

    grid = np.array([0.5, 1.0, 2.0, 3.0, 4.0])
    calls: list[float] = []
    x, fx, profile = profile_maximum(lambda v: calls.append(v) or f(v), grid, xatol=1e-4, maxiter=40)
    assert x == pytest.approx(2.3, abs=2e-3) and fx == pytest.approx(f(x))
    assert 2.0 < x < 3.0 and fx > max(f(g) for g in grid)
    # the grid, then the refined point: sorted, each value the function's at its argument
    assert [p[0] for p in profile] == sorted(p[0] for p in profile) and len(profile) == grid.size + 1
    assert all(v == f(a) for a, v in profile)
    assert calls[: grid.size] == list(grid)


def test_grid_maximum_stands_when_the_search_finds_nothing_better() -> None:
    # a profile flat between the grid's points: the first of the equal maxima is kept
    grid = np.array([1.0, 2.0, 3.0, 4.0])
    x, fx, profile = profile_maximum(lambda v: 1.0 if v >= 2.0 else 0.0, grid, xatol=1e-3, maxiter=12)
    assert (x, fx) == (2.0, 1.0) and len(profile) == grid.size + 1
    # a maximum at the grid's end: the search runs between its one neighbour and the end
    x, _, _ = profile_maximum(lambda v: -((v - 4.2) ** 2), grid, xatol=1e-6, maxiter=50)
    assert 3.0 <= x <= 4.0 and x == pytest.approx(4.0, abs=1e-4)
    # a one-point grid: nothing to refine
    assert profile_maximum(lambda v: -v, np.array([2.0]), xatol=1e-3, maxiter=12) == (2.0, -2.0, [(2.0, -2.0)])
