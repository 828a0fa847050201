"""pi_stiction_tuned (docs/controllers.md): the (S, J) describing function against the stick-slip model,
the predicted limit cycle against a simulated loop, the gains as the describing-function criterion's
optimum, the compensator against pi on a short circulation episode, and bad input."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest

from valve_env.controllers import make_controller
from valve_env.controllers.stiction_tuning import (
    PIStictionTuned,
    StemLoopModel,
    df_tune,
    predict_limit_cycle,
    simc_family,
    sj_describing_function,
    stem_loop_model,
)
from valve_env.evaluation.evaluator import run_episodes
from valve_env.physics import stickslip

CIRC = "ThermoValveStickyCirculation-v0"


def _fundamental(X: float, S: float, J: float, n: int = 4000, cycles: int = 3) -> complex:
    """N(X) from the stick-slip model itself: the input X cos(t) from its peak, the last cycle's fundamental."""
    t = np.linspace(0.0, 2 * np.pi * cycles, n * cycles, endpoint=False)
    y = stickslip.simulate(X * np.cos(t), S, J)
    t, y = t[-n:], y[-n:]
    a = 2.0 / n * np.sum(y * np.cos(t))
    b = 2.0 / n * np.sum(y * np.sin(t))
    return complex(a, -b) / X  # the output's phasor relative to the input cos(t)


@pytest.mark.parametrize(("S", "J"), [(1.0, 1.0), (1.0, 0.4), (1.0, 0.0), (1.3, 0.56)])
def test_describing_function_is_the_stick_slip_models_fundamental(S: float, J: float) -> None:
    for X in (0.55 * S, 0.8 * S, 1.5 * S, 5 * S):
        np.testing.assert_allclose(complex(sj_describing_function(X, S, J)), _fundamental(X, S, J), atol=2e-3)
    assert complex(sj_describing_function(0.4 * S, S, J)) == 0  # below half a band the stem never moves
    assert abs(complex(sj_describing_function(1e4 * S, S, J)) - 1) < 1e-3  # a large swing passes through


def _simulate_loop(m: StemLoopModel, Kp: float, Ti: float, hours: float = 12.0, h: float = 1.0
                   ) -> tuple[float, float]:
    """The loop of the analysis in the time domain (1 s steps): stem (S, J) on ``u - y``, the PI on ``-y``,
    ``tau y' + (1 - K) y = K x(t - theta)``. Returns the period (s) and the outlet's half peak-to-peak
    over the last half."""
    n = int(hours * 3600 / h)
    nd = int(round(m.theta_s / h))
    x_hist = np.zeros(n + nd + 1)
    y, integ = 0.3, 0.0
    st = stickslip.initial_state(0.0, m.S_K, m.J_K, -np.inf, np.inf)
    ys = np.empty(n)
    for k in range(n):
        e = -y
        u = Kp * e + integ
        integ += Kp * h / Ti * e
        st = stickslip.stick_slip_step(u - y, *st, m.S_K, m.J_K, -np.inf, np.inf)
        x_hist[k + nd] = st[0]
        y += h * (m.K * x_hist[k] - (1 - m.K) * y) / m.tau_s
        ys[k] = y
    tail = ys[n // 2 :] - ys[n // 2 :].mean()
    ups = np.nonzero((tail[:-1] < 0) & (tail[1:] >= 0))[0]
    return float(np.median(np.diff(ups)) * h), float(0.5 * (tail.max() - tail.min()))


@pytest.mark.parametrize(("Kp", "Ti"), [(4.0, 929.0), (14.16, 268.0)])
def test_predicted_limit_cycle_matches_a_simulated_one(Kp: float, Ti: float) -> None:
    m = stem_loop_model(CIRC, 0.1)
    c = predict_limit_cycle(m, Kp, Ti)
    assert c is not None
    period, amp = _simulate_loop(m, Kp, Ti)
    assert period == pytest.approx(c.period_s, rel=0.35)
    assert amp == pytest.approx(c.Y_K, rel=0.5)


def test_gains_are_the_describing_function_optimum() -> None:
    m = stem_loop_model(CIRC, 0.1)
    t = df_tune(m)
    assert t.cycle is not None

    def cost(tc: float) -> float:
        c = predict_limit_cycle(m, *simc_family(m, tc))
        assert c is not None
        return c.Y_K * c.omega / math.pi

    best = t.cycle.Y_K * t.cycle.omega / math.pi
    for f in (0.5, 0.8, 1.25, 2.0):
        assert cost(t.tau_c_s * f) >= best * (1 - 1e-6)
    assert (t.Kp, t.Ti_s) == pytest.approx(simc_family(m, t.tau_c_s))
    c = make_controller("pi_stiction_tuned", CIRC)
    assert isinstance(c, PIStictionTuned) and (c.Kp, c.Ti_s) == pytest.approx((t.Kp, t.Ti_s))
    # a band the loop has never seen moves the prediction (and, far enough, the gains)
    wide = df_tune(stem_loop_model(CIRC, 0.3))
    assert wide.cycle is not None and wide.cycle.Y_K > t.cycle.Y_K and wide.Kp != pytest.approx(t.Kp)


def test_reduces_iae_and_reversals_against_pi_on_a_short_circulation_episode() -> None:
    kw = {"horizon_h": 12}
    pi = run_episodes(make_controller("pi", CIRC), CIRC, 1, 0, env_kwargs=kw).iloc[0]
    tuned = run_episodes(make_controller("pi_stiction_tuned", CIRC), CIRC, 1, 0, env_kwargs=kw).iloc[0]
    assert tuned["iae_Kh"] < 0.8 * pi["iae_Kh"]
    assert tuned["reversals"] < 0.7 * pi["reversals"]
    assert tuned["tdis_Kh"] <= pi["tdis_Kh"] + 1e-9


@pytest.mark.parametrize("kw", [{"band_mm": -0.1}, {"band_mm": float("nan")}, {"jump_mm": -1.0},
                                {"Kp": 3.0}])
def test_bad_band_or_config_is_a_clear_error(kw: dict[str, float]) -> None:
    with pytest.raises(ValueError, match="pi_stiction_tuned"):
        make_controller("pi_stiction_tuned", CIRC, **kw)
    with pytest.raises(ValueError, match="does not support"):
        make_controller("pi_stiction_tuned", "ThermoValvePressure-v0")


def test_cli_bad_band_gives_one_error_line(tmp_path: object) -> None:
    r = subprocess.run([sys.executable, "-m", "valve_env.cli", "evaluate", "--env", CIRC, "--episodes", "1",
                        "--controllers", "pi_stiction_tuned:band_mm=-0.1"], capture_output=True, text=True)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("thermovalve: error: ") and "band_mm" in lines[0]
