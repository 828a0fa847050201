"""The grey-box loop model: the valve is the project's stick-slip, the fit finds a simulated band,
and a smooth valve is not called stiction."""

from __future__ import annotations

import numpy as np
import pytest

from valve_env.loops.diagnose import diagnose
from valve_env.loops.model import valve_path
from valve_env.loops.sim import simulate_loop
from valve_env.physics import stickslip


def test_valve_is_the_project_stick_slip() -> None:
    rng = np.random.default_rng(0)
    op = 50 + np.cumsum(rng.normal(0, 0.5, 400))
    for S, J in ((2.0, 2.0), (2.0, 0.0), (3.0, 1.0)):
        np.testing.assert_array_equal(valve_path(op, S, J), stickslip.simulate(op, S, J))
        # stuck after a downward motion: the mirror image of the same model
        np.testing.assert_allclose(valve_path(op, S, J, -1.0), -stickslip.simulate(-op, S, J), atol=1e-12)
    np.testing.assert_array_equal(valve_path(op, 0.0, 0.0), op)


@pytest.mark.parametrize(("process", "S", "J"), [("pressure", 3.0, 1.5), ("temperature", 2.5, 2.0)])
def test_sticky_simulated_loop_gives_its_band(process: str, S: float, J: float) -> None:
    loop, truth = simulate_loop(process, S=S, J=J, seed=101)
    d = diagnose(loop)
    assert d.cause == "stiction"
    st = d.result["stiction"]
    assert abs(st["band_pct"] - S) < 0.25 * S
    assert st["std_pct"] > 0
    names = [f["candidate"] for f in d.result["findings"]]
    assert names == ["linear", "backlash", "stiction"]
    for f in d.result["findings"]:
        assert {"loglik", "lr_stat", "p_value", "delta_bic"} <= set(f)


def test_smooth_simulated_loop_is_not_stiction() -> None:
    loop, _ = simulate_loop("pressure", S=0.0, seed=102)
    assert diagnose(loop).cause != "stiction"
