"""Loop records from ThermoValve-v0 under the project's PI (the diagnosis of these is NOT yet right,
docs/loops.md; this checks the recorder)."""

from __future__ import annotations

import numpy as np

from valve_env.loops.envloop import record_env_loop
from valve_env.loops.io import check_loop


def test_env_loop_record_is_a_valid_loop_csv() -> None:
    smooth = record_env_loop(None, seed=0, hours=1.0, warmup_h=2.5)
    sticky = record_env_loop(0.04, seed=0, hours=1.0, warmup_h=2.5)
    for loop in (smooth, sticky):
        assert loop.n == 120 and loop.dt == 30.0
        assert np.all((loop.op >= 0) & (loop.op <= 100))
        assert 40.0 < loop.sp.mean() < 80.0
        cols = {"time_s": loop.time_s, "sp": loop.sp, "pv": loop.pv, "op": loop.op}
        assert check_loop(cols, min_samples=100).n == loop.n
    # the sticky stem changes the loop's behaviour
    assert not np.allclose(smooth.op, sticky.op)
