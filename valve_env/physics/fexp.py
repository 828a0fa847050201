"""``fexp``: the exponential the physics uses, written so that compilers can vectorise it.

numba calls the C library's ``exp`` for ``np.exp``. That call cannot be vectorised here
(this llvmlite build has no SVML), so every loop over environments that needs an
exponential ran one scalar call per environment. ``fexp`` is plain arithmetic instead,
the textbook reduction (Cody and Waite; Muller, *Elementary Functions*, 2016, ch. 11):

    x = k ln2 + r,   |r| <= ln2 / 2,   k an integer
    exp(x) = 2**k * p(r),   p = the degree-13 Taylor polynomial of exp

with ln2 split into a short high part (exact ``k * LN2_HI`` for |k| < 2**11) and a low
part. The truncation error of ``p`` is below 4e-18 on |r| <= ln2 / 2; the result is
within 1 ulp of the correctly rounded exp on the whole range (checked against libm in
``tests/physics/test_fexp.py``). ``2**k`` is built from the bits of an IEEE double
(``(k + 1023) << 52``) in compiled code and by ``np.ldexp`` in Python: both exact, so the
compiled and the interpreted ``fexp`` agree bit for bit.

Arguments are clamped to [-708, 709] (exp(-708) = 3.3e-308, the bottom of the normal
range; exp(709) = 8.2e307); a non-finite argument gives NaN. The physics' arguments are
finite and well inside the range.
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic, overload, register_jitable

LOG2E = 1.4426950408889634
LN2_HI = 6.93145751953125e-1  # 22 significant bits: k * LN2_HI is exact for |k| < 2**11
LN2_LO = 1.42860682030941723212e-6
X_MIN = -708.0
X_MAX = 709.0
# Taylor coefficients 1/k!, k = 2 .. 13
C2 = 1.0 / 2.0
C3 = 1.0 / 6.0
C4 = 1.0 / 24.0
C5 = 1.0 / 120.0
C6 = 1.0 / 720.0
C7 = 1.0 / 5040.0
C8 = 1.0 / 40320.0
C9 = 1.0 / 362880.0
C10 = 1.0 / 3628800.0
C11 = 1.0 / 39916800.0
C12 = 1.0 / 479001600.0
C13 = 1.0 / 6227020800.0


@intrinsic
def _bits_to_double(typingctx, bits):  # type: ignore[no-untyped-def]
    """Reinterpret an int64 as the float64 with the same bits (no conversion)."""
    sig = types.float64(types.int64)

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        return builder.bitcast(args[0], ir.DoubleType())

    return sig, codegen


def pow2(k):  # type: ignore[no-untyped-def]
    """2**k for integral float k in [-1022, 1023], exactly."""
    return np.ldexp(1.0, np.nan_to_num(np.asarray(k, dtype=float)).astype(np.int64))


@overload(pow2)
def _pow2_compiled(k):  # type: ignore[no-untyped-def]
    def impl(k):  # type: ignore[no-untyped-def]
        return _bits_to_double((np.int64(k) + 1023) << 52)

    return impl


@register_jitable
def fexp(x):  # type: ignore[no-untyped-def]
    """exp(x) within 1 ulp, vectorisable (see the module docstring); scalars or arrays."""
    xc = np.minimum(np.maximum(x, X_MIN), X_MAX)
    k = np.floor(xc * LOG2E + 0.5)
    r = (xc - k * LN2_HI) - k * LN2_LO
    p = C13
    p = p * r + C12
    p = p * r + C11
    p = p * r + C10
    p = p * r + C9
    p = p * r + C8
    p = p * r + C7
    p = p * r + C6
    p = p * r + C5
    p = p * r + C4
    p = p * r + C3
    p = p * r + C2
    p = p * r + 1.0
    p = p * r + 1.0
    # x - x is 0 for a finite x and NaN otherwise (the clamp would hide a NaN)
    return p * pow2(k) + (x - x)
