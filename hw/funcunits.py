"""Function units of the datapath, bit-true: reciprocal square root and the nonlinear damper tables.

Both are vectorised NumPy int64 models that the hardware (Amaranth) reproduces bit for bit. Every
intermediate has a stated format, every runtime rounding is `shift_round` (round to nearest, ties up),
and every clamp of a value that does not fit its format is a saturation counted in a `Saturations`
object under the unit's name. Constants (tables, scale factors) are computed once at construction, in
float64 or exact integer arithmetic; they are what the hardware's ROMs and constant operands hold.

Products wider than 62 bits (the Newton steps of a 32-bit-output Rsqrt) are formed exactly from two
partial products of one operand split in two, or from 24-bit limbs (`_mul_shift_round`): the result is the
exactly rounded product, as from a wide hardware multiplier.
"""
from __future__ import annotations

import math
from fractions import Fraction

import numpy as np

from .fixed import Saturations, Shape, _shift_round_owned, shift_round

MAX_UNIT_WIDTH = 32          # widest input/output format of a function unit
_LIMB = 24
_LIMB_MASK = (1 << _LIMB) - 1


# ---------------------------------------------------------------------------------------------- helpers

def _mul_shift_round(a: np.ndarray, b: np.ndarray, s: int, product_bits: int, b_bits: int = 48) -> np.ndarray:
    """round(a * b / 2^s), round to nearest ties up, exact, for non-negative int64 a, b < 2^48 and s >= 0.

    `product_bits` is a static bound on the bit length of a * b and `b_bits` one on b's (from the operands'
    formats). Up to 62 bits the product is formed directly in int64. A wider product is, when some split
    point k <= s keeps both partial products within 61 bits (k >= product_bits - 61, k <= 61 - b_bits,
    s <= 61), formed from a = ah 2^k + al (al = a mod 2^k):
        floor((a b + 2^(s-1)) / 2^s) = floor((ah b + floor((al b + 2^(s-1)) / 2^k)) / 2^(s-k)),
    exact as floor((n + x) / m) = floor((n + floor(x)) / m) for integers n and m >= 1 and real x. Otherwise
    both operands are split into 24-bit limbs a = a1 2^24 + a0, b = b1 2^24 + b0 whose partial products
    (< 2^49) are summed exactly. The caller guarantees that the rounded result fits in 62 bits.
    """
    if s < 0:
        raise ValueError("shift must be non-negative")
    if product_bits <= 62 and s <= 62:
        return shift_round(a * b, s)
    k_lo, k_hi = max(product_bits - 61, 1), min(61 - b_bits, s)
    if k_lo <= k_hi and s <= 61:
        k = (k_lo + k_hi) // 2                # the middle: the most headroom on both partial products
        lo = (a & ((1 << k) - 1)) * b         # < 2^(k + b_bits)
        lo += 1 << (s - 1)
        lo >>= k
        hi = (a >> k) * b                     # <= a b 2^-k < 2^(product_bits - k)
        hi += lo
        hi >>= s - k
        return hi
    a1, a0 = a >> _LIMB, a & _LIMB_MASK
    b1, b0 = b >> _LIMB, b & _LIMB_MASK
    c0 = a0 * b0                         # weight 2^0,  < 2^48
    c1 = a1 * b0 + a0 * b1               # weight 2^24, < 2^49
    c2 = a1 * b1                         # weight 2^48, < 2^48
    if s > 0:                            # the rounding constant 2^(s-1), added to the limb that holds it
        r = s - 1
        if r < _LIMB:
            c0 = c0 + (1 << r)
        elif r < 2 * _LIMB:
            c1 = c1 + (1 << (r - _LIMB))
        else:
            c2 = c2 + (1 << (r - 2 * _LIMB))
    # carry-normalise: p = t2 2^48 + l1 2^24 + l0 with l0, l1 in [0, 2^24)
    l0 = c0 & _LIMB_MASK
    c1 = c1 + (c0 >> _LIMB)
    l1 = c1 & _LIMB_MASK
    t2 = c2 + (c1 >> _LIMB)
    # floor(p / 2^s), exactly (floor((n + e) / m) = floor(n / m) for integers n, m >= 1 and 0 <= e < 1)
    if s <= _LIMB:
        return (t2 << (2 * _LIMB - s)) + (l1 << (_LIMB - s)) + (l0 >> s)
    if s <= 2 * _LIMB:
        return (t2 << (2 * _LIMB - s)) + (l1 >> (s - _LIMB))
    return t2 >> (s - 2 * _LIMB)


def _bit_length(x: np.ndarray) -> np.ndarray:
    """Bit length (1-based position of the leading one) of positive int64 values < 2^53.

    The int -> float64 conversion is exact below 2^53, and a positive float64 x = 1.f 2^(E - 1023) has the
    biased exponent E in bits 52-62 of its word: the bit length is E - 1022 (as np.frexp's exponent; powers
    of two included: 2^j has E = j + 1023).
    """
    n = x.astype(np.float64).view(np.int64) >> 52
    n -= 1022
    return n


def _check_shape(name: str, shape) -> Shape:
    if not isinstance(shape, Shape):
        raise ValueError(f"{name} must be a fixed-point Shape (SQ(i, f) or UQ(i, f)), got {shape!r}")
    if shape.width > MAX_UNIT_WIDTH:
        raise ValueError(f"{name} {shape} is {shape.width} bits wide; function units take at most "
                         f"{MAX_UNIT_WIDTH}-bit formats")
    return shape


def _check_int(name: str, value, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be an integer in {lo}..{hi}, got {value!r}")
    if not lo <= int(value) <= hi:
        raise ValueError(f"{name} must be in {lo}..{hi}, got {value}")
    return int(value)


def _check_real(name: str, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a real number, got {value!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {v}")
    return v


def _check_raw(raw, shape: Shape, what: str) -> np.ndarray:
    x = np.asarray(raw)
    if x.dtype.kind not in "iu":
        raise ValueError(f"{what}: raw inputs must be integers, got dtype {x.dtype}")
    x = np.asarray(x, np.int64)          # no copy: the units never write into their input
    if x.size and (int(x.min()) < shape.min_raw or int(x.max()) > shape.max_raw):
        raise ValueError(f"{what}: raw inputs outside {shape} (raw range {shape.min_raw}..{shape.max_raw})")
    return x


def _round_raw(value: np.ndarray, f: int) -> np.ndarray:
    """Real values to raw integers with f fraction bits: nearest, ties up (as Shape.from_float), unclamped."""
    return np.floor(np.asarray(value, np.float64) * 2.0 ** f + 0.5).astype(np.int64)


# ------------------------------------------------------------------------------------------------ rsqrt

class Rsqrt:
    """Reciprocal square root y = 1/sqrt(v) of a positive fixed-point input, bit-true.

    Input raw x in `in_shape` (value v = x 2^-fi, fi = in_shape.f); output raw in `out_shape`
    (fo = out_shape.f). Internal mantissa width M = out_shape.width + guard_bits; the iterate y has
    Y = M fraction bits. All integers are non-negative in steps 2-5.

    1. Non-positive input: x <= 0 gives the out_shape maximum, one saturation counted per element.
    2. Normalise. n = bit length of x (1-based position of its leading one), k = n or n + 1 so that
       k - fi is even (k = n + ((n - fi) mod 2)), e = (k - fi) / 2 (signed integer). The mantissa
       mant = x 2^-k lies in [0.25, 1). It is held as m_raw in UQ(0, M):
       m_raw = x << (M - k) when k <= M (exact), else shift_round(x, k - M), clamped to 2^M - 1 if the
       rounding reaches 2^M (a property of the normalisation, not a saturation). Write m = m_raw 2^-M.
    3. Seed. idx = m_raw >> (M - seed_bits), in [2^(seed_bits-2), 2^seed_bits). A ROM of
       3 * 2^(seed_bits-2) words (address idx - 2^(seed_bits-2)) holds y0 = 1/sqrt(c) rounded to
       nearest into UQ(2, Y), c = (idx + 1/2) 2^-seed_bits the midpoint of the index's mantissa interval
       (built with exact integer square roots). y = y0, in UQ(2, Y).
    4. Newton, newton_steps times, y <- y (3 - m y^2) / 2:
         y2 = shift_round(y * y, Y)          UQ(3, Y)   y^2
         h  = shift_round(m_raw * y2, M)     UQ(3, Y)   m y^2 (~ 1)
         t  = 3 2^Y - h                      UQ(2, Y)   3 - m y^2, in (0, 3]
         y  = shift_round(y * t, Y + 1)      UQ(2, Y)   y t / 2 (the halving folded into the shift)
    5. Denormalise: 1/sqrt(v) = (1/sqrt(mant)) 2^-e, so raw_out = shift_round(y, Y + e - fo) (a left
       shift when Y + e - fo < 0), then saturated into out_shape (counted). With guard_bits >= 1 a left
       shift only occurs for outputs that overflow (an output that fits has Y + e - fo >= guard_bits).
    The Newton products are formed exactly (up to 2 (Y + 2) = 2 out.width + 2 guard_bits + 4 bits) and
    then rounded; a 32-bit output with 2 guard bits needs 36 x 36-bit products.

    Error bound (`internal_relative_error_bound`, `error_bound`, `max_relative_error_bound`): write the
    iterate as y = (1 + eps) / sqrt(m).
    - Seed: for idx's interval [a, a + 2^-seed_bits) the table value's error is largest at an end,
      E0 = max over the table of |y0 sqrt(a) - 1|, |y0 sqrt(a + 2^-seed_bits) - 1| (~2^-seed_bits,
      worst in the lowest interval, a = 1/4; it includes the seed's rounding).
    - Newton: exactly, y (3 - m y^2)/2 = (1 + eps') / sqrt(m) with eps' = -eps^2 (3 + eps) / 2.
      The three roundings (each |d| <= rho = 2^-(Y+1)) change the new y by
      -y (m d1 + d2) / 2 + d3, i.e. relatively by at most (1 + E)(1 + m) rho / 2 + sqrt(m) rho <= (2 + E) rho.
      So E_(j+1) = E_j^2 (3 + E_j) / 2 + (2 + E_j) rho.
    - Mantissa rounding (only when an input can have k > M): m = mant (1 + eta), |eta| <= 2^(1-M), which
      scales 1/sqrt by at most 1/sqrt(1 - 2^(1-M)) - 1 =: eps_m.
    - Internal bound E_int = (1 + E_N)(1 + eps_m) - 1 on |y 2^-Y 2^-e sqrt(v) - 1|.
    - Output: the final rounding adds at most half an output LSB, so for every unsaturated output
      |out - 1/sqrt(v)| <= E_int / sqrt(v) + 2^-(fo+1)   (`error_bound(v)`), and relative to 1/sqrt(v) over
      the whole input range: E_int + 2^-(fo+1) sqrt(v_max)   (`max_relative_error_bound()`).
    Newton approaches from below (eps' <= 0): where its error dominates the output rounding, outputs are
    biased low by roughly a third of E_N (measured: mean relative error -0.06 to -0.13 E_int).
    """

    def __init__(self, in_shape: Shape, out_shape: Shape, seed_bits: int = 9, newton_steps: int = 1,
                 guard_bits: int = 2, name: str = "rsqrt"):
        self.in_shape = _check_shape("Rsqrt in_shape", in_shape)
        self.out_shape = _check_shape("Rsqrt out_shape", out_shape)
        self.seed_bits = _check_int("Rsqrt seed_bits", seed_bits, 3, 12)
        self.newton_steps = _check_int("Rsqrt newton_steps", newton_steps, 0, 3)
        self.guard_bits = _check_int("Rsqrt guard_bits", guard_bits, 0, 8)
        self.name = str(name)
        self.M = out_shape.width + self.guard_bits
        if self.M < self.seed_bits:
            raise ValueError(f"Rsqrt: the internal mantissa (out_shape {out_shape} width + guard_bits = "
                             f"{self.M} bits) is narrower than seed_bits = {self.seed_bits}")
        if in_shape.max_raw < 1:
            raise ValueError(f"Rsqrt in_shape {in_shape} has no positive values")
        self.Y = self.M
        # seed ROM: y0 = round(2^Y / sqrt(c)), c = (2 idx + 1) 2^-(sb+1), i.e. round(sqrt(Q)) with
        # Q = 2^(2Y+sb+1) / (2 idx + 1); round(sqrt(Q)) = (floor(sqrt(4Q)) + 1) // 2, and
        # floor(sqrt(4Q)) = isqrt(floor(4Q)) (exact integer arithmetic)
        sb, Y = self.seed_bits, self.Y
        self.idx_lo = 1 << (sb - 2)
        num = 1 << (2 * Y + sb + 3)
        self.seed_table = np.array([(math.isqrt(num // (2 * i + 1)) + 1) // 2
                                    for i in range(self.idx_lo, 1 << sb)], dtype=np.int64)
        # the largest normalisation exponent k any input can have: mantissa rounding happens iff k > M
        self.k_max = int(in_shape.max_raw).bit_length() + 1
        self._bound = None
        # the ROM addressed by idx itself (idx_lo unused words below it: idx >= idx_lo), saving a subtraction
        self._rom = np.concatenate([np.zeros(self.idx_lo, np.int64), self.seed_table])
        # an upper bound on the denormalising shift s = Y + e - fo (k <= k_max, step 5)
        self._s_max = Y - out_shape.f + (self.k_max - in_shape.f + 1) // 2

    # ---- the unit
    def _core(self, raw):
        """Steps 2-4: (x > 0 mask, y in UQ(2, Y), e) for raw inputs."""
        x = _check_raw(raw, self.in_shape, f"Rsqrt({self.in_shape} -> {self.out_shape})")
        M, Y, fi = self.M, self.Y, self.in_shape.f
        positive = x > 0
        xs = x if positive.all() else np.where(positive, x, 1)
        # 2. normalise
        n = _bit_length(xs)
        k = n + ((n - fi) & 1)
        if self.k_max <= M:            # no input has k > M: m = x << (M - k) < 2^M, exact
            m = xs << (M - k)
        else:
            left = np.maximum(M - k, 0)
            right = np.maximum(k - M, 0)
            m = ((xs << left) + ((1 << right) >> 1)) >> right   # exact left shift or shift_round right
            m = np.minimum(m, (1 << M) - 1)
        e = (k - fi) >> 1                                        # exact: k - fi is even
        # 3. seed
        y = self._rom[m >> (M - self.seed_bits)]
        # 4. Newton steps (products exact, then rounded)
        for _ in range(self.newton_steps):
            y2 = _mul_shift_round(y, y, Y, 2 * (Y + 2), Y + 2)          # UQ(3, Y)
            h = _mul_shift_round(m, y2, M, M + Y + 3, Y + 3)            # UQ(3, Y)
            t = (3 << Y) - h                                            # UQ(2, Y)
            y = _mul_shift_round(y, t, Y + 1, 2 * (Y + 2), Y + 2)       # UQ(2, Y)
        return positive, y, e

    def internal(self, raw: np.ndarray) -> np.ndarray:
        """The result before the output rounding, y 2^-Y 2^-e, as float64 (nan where x <= 0)."""
        positive, y, e = self._core(raw)
        val = np.ldexp(y.astype(np.float64), (-self.Y - e).astype(np.int32))
        return np.where(positive, val, np.nan)

    def __call__(self, raw: np.ndarray, sat: Saturations | None = None) -> np.ndarray:
        positive, y, e = self._core(raw)
        Y = self.Y
        # 5. denormalise: shift_round(y, s), s = Y + e - fo, per element; then saturate
        out = self.out_shape
        s = e + (Y - out.f)
        if s.size and s.min() >= 0:                # the common case: right shifts only
            # y < 2^(Y+2): a shift beyond Y + 3 (up to 62, no int64 overflow) still gives 0, as the clamp does
            rs = s if self._s_max <= 62 else np.minimum(s, Y + 3)
            res = (y + ((1 << rs) >> 1)) >> rs
        else:
            rs = np.minimum(np.maximum(s, 0), Y + 3)   # y < 2^(Y+2): any right shift >= Y + 3 gives 0
            ls = np.minimum(np.maximum(-s, 0), 62)     # y > 2^(Y-1) >= 1: shifts >= 33 overflow anyway
            # a left-shifted y overflows iff y > max_raw >> ls; clip it to (max_raw >> ls) + 1 first, so the
            # shift itself never overflows int64 and the saturation below still sees (and counts) it
            yl = np.where(ls > 0, np.minimum(y, (out.max_raw >> ls) + 1), y)
            res = ((yl << ls) + ((1 << rs) >> 1)) >> rs
        if not positive.all():
            res = np.where(positive, res, out.max_raw + 1)         # 1. x <= 0: saturate (counted)
        return out.saturate(res, sat, self.name)

    # ---- references and bounds
    @staticmethod
    def reference(value) -> np.ndarray:
        """1/sqrt(value) in float64 (inf for 0, nan for negative values)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return 1.0 / np.sqrt(np.asarray(value, np.float64))

    def seed_relative_error(self) -> float:
        """E0: the largest |y0 sqrt(mant) - 1| over all seed intervals (ends included)."""
        sb = self.seed_bits
        w = 2.0 ** -sb
        a = np.arange(self.idx_lo, 1 << sb, dtype=np.float64) * w
        y0 = self.seed_table.astype(np.float64) * 2.0 ** -self.Y
        return float(np.max(np.maximum(np.abs(y0 * np.sqrt(a) - 1), np.abs(y0 * np.sqrt(a + w) - 1))))

    def internal_relative_error_bound(self) -> float:
        """E_int: bound on the relative error of y 2^-Y 2^-e before the output rounding."""
        if self._bound is None:
            E = self.seed_relative_error()
            rho = 2.0 ** -(self.Y + 1)
            for _ in range(self.newton_steps):
                E = E * E * (3 + E) / 2 + (2 + E) * rho
            eps_m = 1 / math.sqrt(1 - 2.0 ** (1 - self.M)) - 1 if self.k_max > self.M else 0.0
            self._bound = (1 + E) * (1 + eps_m) - 1
        return self._bound

    def error_bound(self, value) -> np.ndarray:
        """Bound on |out - 1/sqrt(value)| (real units) for inputs whose output does not saturate."""
        return self.internal_relative_error_bound() * self.reference(value) + 0.5 * self.out_shape.lsb

    def max_relative_error_bound(self) -> float:
        """Bound on |out sqrt(v) - 1| over every positive input whose output does not saturate."""
        return self.internal_relative_error_bound() + 0.5 * self.out_shape.lsb * math.sqrt(self.in_shape.max_value)

    def to_dict(self) -> dict:
        return {"unit": "rsqrt", "name": self.name, "in": str(self.in_shape), "out": str(self.out_shape),
                "seed_bits": self.seed_bits, "newton_steps": self.newton_steps, "guard_bits": self.guard_bits,
                "mantissa_bits": self.M, "rom_words": len(self.seed_table), "rom_word_bits": self.Y + 2,
                "internal_relative_error_bound": self.internal_relative_error_bound(),
                "max_relative_error_bound": self.max_relative_error_bound()}


# ------------------------------------------------------------------------------------------------ damper

class DamperTable:
    """The force-dependent damper c2(f), c1 + c2(f) and 1/(c1 + c2(f)) by table and linear interpolation.

    Physics: c2(f) = c_max for f <= f1, A exp(-B f) for f1 <= f <= f2, c_min for f >= f2, with
    B = ln(c_max / c_min) / (f2 - f1), A = c_max exp(B f1). All parameters are real numbers in the units
    of the formats (hardware units). Input: f_raw = |T| in f_shape (ff = f_shape.f fraction bits).
    Outputs: c2 and c1 + c2 in c2_shape, 1/(c1 + c2) in inv_shape. S = segments_log2, P = frac_bits.

    Constants (construction time, exact rational arithmetic):
    - comparator thresholds F1 = floor(f1 2^ff) (clipped to f_shape.max_raw) and F2 = ceil(f2 2^ff)
      (clipped to f_shape.max_raw + 1): f_raw <= F1 exactly when f <= f1, f_raw >= F2 exactly when f >= f2;
    - K = 2^S / (f2 - f1) (segments per unit force) as an unsigned operand of scale_bits significant bits,
      rounded to nearest: K_raw in [2^(scale_bits-1), 2^scale_bits], K_q = K_raw 2^-kf;
    - the offset OFF = round(f1 2^ff K_raw), an integer (< 2^61) in the units of the product f_raw K_raw;
    - tables of 2^S + 1 entries at the breakpoints f_j = f1 + j (f2 - f1) / 2^S: c2(f_j) rounded to
      nearest into c2_shape, and 1/(c1 + c2(f_j)) rounded to nearest into inv_shape. An entry that does
      not fit its format is clamped to it and flagged (one flag bit per ROM word): every element that
      uses a flagged entry counts one saturation per output;
    - c1q = c1 rounded to nearest to c2_shape's fraction bits (not clamped; see c12 below).

    Per element (integers; fraction bits in brackets):
    1. f_raw <= F1 (the c_max piece): pos = 0. f_raw >= F2 (the c_min piece): the end point,
       idx = 2^S - 1, frac = 2^P. These are the function's own flat pieces, exact, not saturations.
    2. Otherwise D = f_raw K_raw - OFF [ff + kf] (0 <= D < 2^61) and pos = shift_round(D, ff + kf - P) [P],
       the position in segments (a left shift when ff + kf - P < 0), limited to the end point 2^(S+P)
       (reached only by f within (f2 - f1)|K_q/K - 1| of f2 through the rounding of K: not a saturation).
    3. idx = pos >> P, frac = pos & (2^P - 1) (the end point: idx = 2^S - 1, frac = 2^P).
    4. value = tab[idx] + shift_round(frac (tab[idx+1] - tab[idx]), P), for both tables: c2 in c2_shape,
       inv in inv_shape. The result lies between the two entries, so it always fits.
    5. c12 = c1q + c2, saturated into c2_shape (counted).

    Error bounds (`error_bounds()`, real units, for elements that do not saturate), with h = (f2 - f1)/2^S:
    - position: between f1 and f2 the unit interpolates at f_eff = f1 + h pos 2^-P with
      |f_eff - f| <= df = (f2 - f1)|K_q/K - 1| + h 2^-P (|OFF - f1 2^ff K_raw| 2^-(ff+kf-P) + 1/2 if step 2
      rounds) (`position_error_bound()`); outside, f_eff = f exactly as far as the function is concerned;
    - linear interpolation of exact breakpoint values: h^2/8 max|g''| (g'' = B^2 c2 for c2, at most
      B^2 c_max; for 1/(c1 + c2): g'' = B^2 u (u - c1)/(c1 + u)^3 with u = c2, maximised over
      u in [c_min, c_max] at the ends and at u = c1 (2 +/- sqrt 3));
    - g and the interpolant are Lipschitz with L = max|g'| (B c_max for c2; for the inverse
      B max u/(c1 + u)^2 over the ends and u = c1): + L df;
    - table rounding (1/2 LSB) plus the interpolation rounding (1/2 LSB): + 1 LSB of the output;
    - c12 adds |c1q 2^-fc - c1| (<= 1/2 LSB) to the c2 bound.
    """

    def __init__(self, f_shape: Shape, c2_shape: Shape, inv_shape: Shape, c1: float, c_min: float,
                 c_max: float, f1: float, f2: float, segments_log2: int = 8, frac_bits: int = 16,
                 scale_bits: int = 25, name: str = "damper"):
        self.f_shape = _check_shape("DamperTable f_shape", f_shape)
        self.c2_shape = _check_shape("DamperTable c2_shape", c2_shape)
        self.inv_shape = _check_shape("DamperTable inv_shape", inv_shape)
        self.S = _check_int("DamperTable segments_log2", segments_log2, 1, 12)
        self.P = _check_int("DamperTable frac_bits", frac_bits, 1, 24)
        self.scale_bits = _check_int("DamperTable scale_bits", scale_bits, 8, 29)
        self.name = str(name)
        c1, c_min, c_max = (_check_real(f"DamperTable {n}", v) for n, v in
                            (("c1", c1), ("c_min", c_min), ("c_max", c_max)))
        f1, f2 = _check_real("DamperTable f1", f1), _check_real("DamperTable f2", f2)
        if not 0 < c_min <= c_max:
            raise ValueError(f"DamperTable: need 0 < c_min <= c_max, got c_min = {c_min:g}, c_max = {c_max:g}")
        if c1 < 0:
            raise ValueError(f"DamperTable: need c1 >= 0, got c1 = {c1:g}")
        if not 0 <= f1 < f2:
            raise ValueError(f"DamperTable: need 0 <= f1 < f2, got f1 = {f1:g}, f2 = {f2:g}")
        if f2 - f1 < f_shape.lsb:
            raise ValueError(f"DamperTable: f2 - f1 = {f2 - f1:g} is below one LSB ({f_shape.lsb:g}) of "
                             f"f_shape {f_shape}; the exponential piece cannot be resolved")
        self.c1, self.c_min, self.c_max, self.f1, self.f2 = c1, c_min, c_max, f1, f2
        self.B = math.log(c_max / c_min) / (f2 - f1)
        self.A = c_max * math.exp(self.B * f1)
        S, P, sb, ff = self.S, self.P, self.scale_bits, f_shape.f
        F1x, F2x = Fraction(f1) * Fraction(2) ** ff, Fraction(f2) * Fraction(2) ** ff   # exact
        self.F1 = min(math.floor(F1x), f_shape.max_raw)
        self.F2 = min(math.ceil(F2x), f_shape.max_raw + 1)
        # K = 2^S / (f2 - f1), rounded to nearest with scale_bits significant bits
        K = Fraction(2 ** S) / (Fraction(f2) - Fraction(f1))
        ex = K.numerator.bit_length() - K.denominator.bit_length()      # 2^(ex-1) <= K < 2^(ex+1)
        if K >= Fraction(2) ** ex:
            ex += 1                                                     # now 2^(ex-1) <= K < 2^ex
        self.kf = sb - ex
        self.K_raw = math.floor(K * Fraction(2) ** self.kf + Fraction(1, 2))
        self.K_q = self.K_raw * 2.0 ** -self.kf
        self.K_rel_error = float(abs(Fraction(self.K_raw) * Fraction(2) ** -self.kf / K - 1))
        self.pos_shift = ff + self.kf - P
        if self.F1 < f_shape.max_raw:                   # the interpolated piece is reachable
            off = F1x * self.K_raw
            self.OFF = math.floor(off + Fraction(1, 2))
            self.OFF_error = float(abs(self.OFF - off))
        else:
            self.OFF, self.OFF_error = 0, 0.0
        # tables at the breakpoints
        j = np.arange((1 << S) + 1, dtype=np.float64)
        c2 = c_max * (c_min / c_max) ** (j / (1 << S))  # = A exp(-B f_j), computed from the end values
        c2[0], c2[-1] = c_max, c_min
        self.breakpoints = f1 + j * (f2 - f1) / (1 << S)
        self.tab_c2, self.clip_c2 = self._rom(c2, c2_shape)
        self.tab_inv, self.clip_inv = self._rom(1.0 / (c1 + c2), inv_shape)
        self.c1_raw = int(_round_raw(c1, c2_shape.f))
        # tab[j + 1] - tab[j] of both tables, precomputed (exact integers): one lookup instead of two
        self._slope_c2, self._slope_inv = np.diff(self.tab_c2), np.diff(self.tab_inv)

    @staticmethod
    def _rom(values, shape: Shape):
        raw = _round_raw(values, shape.f)
        clipped = (raw < shape.min_raw) | (raw > shape.max_raw)
        return np.clip(raw, shape.min_raw, shape.max_raw), clipped

    # ---- the unit
    def __call__(self, f_raw: np.ndarray, sat: Saturations | None = None):
        f = _check_raw(f_raw, self.f_shape, f"DamperTable({self.f_shape})")
        S, P = self.S, self.P
        cap = 1 << (S + P)
        high = f >= self.F2                                      # 1. the flat pieces
        D = np.maximum(f * self.K_raw - self.OFF, 0)             # 2. (>= 0 wherever it is used)
        s = self.pos_shift
        if s > 0:
            pos = np.minimum(_shift_round_owned(D, min(s, 62)), cap)    # D < 2^61: shifts >= 62 give 0
        else:
            lim = 1 << max(S + P + s, 0)                         # D << -s >= cap iff D >= lim
            pos = np.where(D >= lim, cap, np.minimum(D, lim) << -s)
        if self.F1 < self.f_shape.max_raw:
            # f <= F1 already has D = 0, so pos = 0: f K_raw <= F1x K_raw < OFF + 1/2 (F1 <= F1x)
            pos = np.where(high, cap, pos)
        else:
            pos = np.where(f <= self.F1, 0, np.where(high, cap, pos))
        idx = np.minimum(pos >> P, (1 << S) - 1)                 # 3. (pos <= cap: the end point gives
        frac = pos - (idx << P)                                  #     idx = 2^S - 1, frac = 2^P)
        c2 = self._interp(self.tab_c2, self._slope_c2, self.clip_c2, idx, frac, sat)      # 4.
        inv = self._interp(self.tab_inv, self._slope_inv, self.clip_inv, idx, frac, sat)
        c12 = self.c2_shape.saturate(c2 + self.c1_raw, sat, self.name)   # 5.
        return c2, c12, inv

    def _interp(self, tab, slope, clipped, idx, frac, sat):
        """tab[idx] + shift_round(frac (tab[idx + 1] - tab[idx]), P), with slope[idx] = tab[idx + 1] - tab[idx]."""
        if sat is not None and clipped.any():
            n = int(np.count_nonzero(clipped[idx] | (clipped[idx + 1] & (frac > 0))))
            if n:
                sat.add(self.name, n)
        return tab[idx] + _shift_round_owned(frac * slope[idx], self.P)

    # ---- references and bounds
    def reference(self, f):
        """(c2, c1 + c2, 1/(c1 + c2)) at real forces f, float64, exact formulas."""
        f = np.asarray(f, np.float64)
        c2 = np.where(f <= self.f1, self.c_max,
                      np.where(f >= self.f2, self.c_min,
                               self.c_max * np.exp(-self.B * np.clip(f - self.f1, 0.0, self.f2 - self.f1))))
        return c2, self.c1 + c2, 1.0 / (self.c1 + c2)

    def position_error_bound(self) -> float:
        """df: bound on |f_eff - f| (force units) for the point at which the tables are interpolated."""
        h = (self.f2 - self.f1) / (1 << self.S)
        rounding = self.OFF_error * 2.0 ** -self.pos_shift + (0.5 if self.pos_shift > 0 else 0.0)
        return (self.f2 - self.f1) * self.K_rel_error + h * 2.0 ** -self.P * rounding

    def error_bounds(self) -> dict:
        """Bounds on |output - reference| in real units for non-saturated elements, and their parts."""
        c1, cmin, cmax, B = self.c1, self.c_min, self.c_max, self.B
        h = (self.f2 - self.f1) / (1 << self.S)
        df = self.position_error_bound()
        r3 = math.sqrt(3.0)
        cand2 = [u for u in (cmin, cmax, c1 * (2 - r3), c1 * (2 + r3)) if cmin <= u <= cmax]
        d2_inv = B * B * max(abs(u * (u - c1) / (c1 + u) ** 3) for u in cand2)
        cand1 = [u for u in (cmin, cmax, c1) if cmin <= u <= cmax]
        d1_inv = B * max(u / (c1 + u) ** 2 for u in cand1)
        interp_c2 = h * h / 8 * B * B * cmax
        interp_inv = h * h / 8 * d2_inv
        c2 = interp_c2 + B * cmax * df + self.c2_shape.lsb
        inv = interp_inv + d1_inv * df + self.inv_shape.lsb
        c12 = c2 + abs(self.c1_raw * self.c2_shape.lsb - c1)
        return {"c2": c2, "c12": c12, "inv": inv, "position": df,
                "interp_c2": interp_c2, "interp_inv": interp_inv,
                "lipschitz_c2": B * cmax, "lipschitz_inv": d1_inv}

    def to_dict(self) -> dict:
        return {"unit": "damper", "name": self.name, "f": str(self.f_shape), "c2": str(self.c2_shape),
                "inv": str(self.inv_shape), "segments_log2": self.S, "frac_bits": self.P,
                "scale_bits": self.scale_bits, "K_raw": self.K_raw, "K_frac_bits": self.kf, "OFF": self.OFF,
                "F1": self.F1, "F2": self.F2, "c1_raw": self.c1_raw,
                "clipped_entries": int(self.clip_c2.sum() + self.clip_inv.sum()),
                "error_bounds": self.error_bounds()}
