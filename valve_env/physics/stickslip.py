"""Stick-slip of a valve stem: the two-parameter (S, J) data-driven stiction model.

One definition serves every consumer: the thermostatic valve's stem (units: mm of
stem, the input is the demanded opening of the force balance, docs/reference.md,
section 3, stiction) and a control loop's valve (units: % of controller output, the input
is the controller output; valve_env.loops). The functions are pure and
``register_jitable``: plain Python/NumPy when called from Python, compiled inline
by numba in the simulator kernels.

Sources
-------
* Choudhury, M.A.A.S., Thornhill, N.F., Shah, S.L. (2005). Modelling valve
  stiction. *Control Engineering Practice* 13(5), 641-658: the parametrisation by
  ``S`` (deadband plus stickband) and ``J`` (slip jump), and the rule that a
  moving valve sticks when its input stops or reverses.
* Kano, M., Maruta, H., Kugemoto, H., Shimizu, K. (2004). Practical model and
  detection algorithm for valve stiction. *IFAC DYCOPS*, Boston: the algorithm
  written with the direction of the last motion ``d`` kept in the state, so that a
  stuck valve that is pushed on in its old direction breaks away after ``J``, and
  one that is pushed back after ``S``.

The algorithm, per sample (input ``u`` clipped to ``[lo, hi]``, ``du = u - u_prev``)::

    if du * du_prev <= 0 and moving:      # the input stops or reverses: the stem sticks
        u_s = u_prev; stuck
    if moving:                            # it follows the input, lagging by the deadband
        y = u - d (S - J) / 2
    elif -d (u - u_s) > S:                # pushed back beyond deadband + stickband: slips
        d = -d; y = u - d (S - J) / 2; moving
    elif d (u - u_s) > J:                 # pushed on beyond the stickband: slips
        y = u - d (S - J) / 2; moving
    else:                                 # still stuck
        y = y_prev

``J = S`` is stick-slip without offset: the stem stays put until the input has
moved ``S`` away from where it stuck, then jumps onto the input and follows it
until the input stops or reverses (this is how it re-sticks). ``J < S`` lands
short of the input (undershoot), ``J > S`` beyond it (overshoot), ``J = 0`` is a
pure deadband (backlash) of width ``S``. ``S = J = 0`` is a frictionless valve.
The output is clipped to ``[lo, hi]`` (end stops).

State (a tuple, in this order): ``y, u_prev, du_prev, u_s, stuck, d`` (stuck 1.0
or 0.0; d +1.0 or -1.0). :func:`initial_state` gives the state of a valve that came
to rest at its input after a motion upwards (or, with ``d0 = -1``, downwards).
"""

from __future__ import annotations

import numpy as np
from numba.extending import register_jitable

#: number of state variables of :func:`stick_slip_step`
N_STATE = 6
STATE_NAMES: tuple[str, ...] = ("y", "u_prev", "du_prev", "u_s", "stuck", "d")


@register_jitable
def initial_state(u0, S, J, lo, hi, d0=1.0):  # type: ignore[no-untyped-def]
    """A valve at rest where its input ``u0`` left it after a motion upwards (``d0 = +1``, the default:
    stuck, ``d = +1``, ``y = u0 - (S - J) / 2``: on ``u0`` itself when ``J = S``) or downwards
    (``d0 = -1``: the mirror image, ``y = u0 + (S - J) / 2``)."""
    u = min(max(u0, lo), hi)
    y = min(max(u - d0 * (S - J) * 0.5, lo), hi)
    return y, u, 0.0, u, 1.0, d0


@register_jitable
def stick_slip_step(u, y, u_prev, du_prev, u_s, stuck, d, S, J, lo, hi):  # type: ignore[no-untyped-def]
    """One sample of the (S, J) model; returns the new state ``(y, u_prev, du_prev, u_s, stuck, d)``
    (``u_prev`` and ``du_prev`` of the new state are this sample's input and its increment)."""
    u = min(max(u, lo), hi)
    du = u - u_prev
    if du * du_prev <= 0.0 and stuck == 0.0:
        u_s = u_prev
        stuck = 1.0
    if stuck == 0.0:
        y = u - d * (S - J) * 0.5
    elif -d * (u - u_s) > S:
        d = -d
        y = u - d * (S - J) * 0.5
        stuck = 0.0
    elif d * (u - u_s) > J:
        y = u - d * (S - J) * 0.5
        stuck = 0.0
    y = min(max(y, lo), hi)
    # a zero increment keeps the last direction of the input, so a pause does not count as a reversal twice
    return y, u, du if du != 0.0 else du_prev, u_s, stuck, d


@register_jitable
def stick_slip_path(u, S, J, lo, hi, out, d0=1.0):  # type: ignore[no-untyped-def]
    """Run the model over a whole input sequence ``u`` (valve at rest at ``u[0]`` after a motion in the
    direction ``d0``, :func:`initial_state`); writes ``out``."""
    y, u_prev, du_prev, u_s, stuck, d = initial_state(u[0], S, J, lo, hi, d0)
    out[0] = y
    for k in range(1, u.shape[0]):
        y, u_prev, du_prev, u_s, stuck, d = stick_slip_step(u[k], y, u_prev, du_prev, u_s, stuck, d, S, J, lo, hi)
        out[k] = y
    return out


def simulate(u: np.ndarray, S: float, J: float | None = None, lo: float = -np.inf, hi: float = np.inf) -> np.ndarray:
    """Python convenience: the valve positions for the inputs ``u`` (``J`` defaults to ``S``)."""
    u = np.ascontiguousarray(u, dtype=float)
    if u.ndim != 1 or u.size == 0:
        raise ValueError("u must be a non-empty 1-d array")
    if not (np.isfinite(S) and S >= 0):
        raise ValueError(f"S must be finite and >= 0, got {S!r}")
    J = S if J is None else J
    if not (np.isfinite(J) and J >= 0):
        raise ValueError(f"J must be finite and >= 0, got {J!r}")
    return np.asarray(stick_slip_path(u, float(S), float(J), float(lo), float(hi), np.empty_like(u)))


__all__ = ["N_STATE", "STATE_NAMES", "initial_state", "stick_slip_step", "stick_slip_path", "simulate"]
