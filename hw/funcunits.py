"""Function units of the datapath, bit-true: reciprocal square root (by Newton, `Rsqrt`, or by table and
linear interpolation, `RsqrtTable`) and inverse tables (the damper).

All are vectorised NumPy int64 models that the hardware (Amaranth) reproduces bit for bit. Every
intermediate has a stated format, every runtime rounding is `shift_round` (round to nearest, ties up),
and every clamp of a value that does not fit its format is a saturation counted in a `Saturations`
object under the unit's name. Constants (tables, scale factors) are computed once at construction, in
float64 or exact integer arithmetic; they are what the hardware's ROMs and constant operands hold.

Products wider than 62 bits (the Newton steps of a 32-bit-output Rsqrt, the interpolation of a wide
RsqrtTable) are formed exactly from two
partial products of one operand split in two, or from 24-bit limbs (`_mul_shift_round`): the result is the
exactly rounded product, as from a wide hardware multiplier.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from fractions import Fraction
from typing import Callable

import numpy as np

from .fixed import FormatError, Saturations, Shape, _shift_round_owned, shift_round

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
        raise FormatError("shift must be non-negative")
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
        raise FormatError(f"{name} must be a fixed-point Shape (SQ(i, f) or UQ(i, f)), got {shape!r}")
    if shape.width > MAX_UNIT_WIDTH:
        raise FormatError(f"{name} {shape} is {shape.width} bits wide; function units take at most "
                         f"{MAX_UNIT_WIDTH}-bit formats")
    return shape


def _check_int(name: str, value, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise FormatError(f"{name} must be an integer in {lo}..{hi}, got {value!r}")
    if not lo <= int(value) <= hi:
        raise FormatError(f"{name} must be in {lo}..{hi}, got {value}")
    return int(value)


def _check_real(name: str, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise FormatError(f"{name} must be a real number, got {value!r}") from None
    if not math.isfinite(v):
        raise FormatError(f"{name} must be finite, got {v}")
    return v


def _check_raw(raw, shape: Shape, what: str) -> np.ndarray:
    x = np.asarray(raw)
    if x.dtype.kind not in "iu":
        raise FormatError(f"{what}: raw inputs must be integers, got dtype {x.dtype}")
    x = np.asarray(x, np.int64)          # no copy: the units never write into their input
    if x.size and (int(x.min()) < shape.min_raw or int(x.max()) > shape.max_raw):
        raise FormatError(f"{what}: raw inputs outside {shape} (raw range {shape.min_raw}..{shape.max_raw})")
    return x


def _round_raw(value: np.ndarray, f: int) -> np.ndarray:
    """Real values to raw integers with f fraction bits: nearest, ties up (as Shape.from_float), unclamped."""
    return np.floor(np.asarray(value, np.float64) * 2.0 ** f + 0.5).astype(np.int64)


# ------------------------------------------------------------------------------------------------ rsqrt

def _rsqrt_normalise(x: np.ndarray, M: int, fi: int, k_max: int):
    """Step 2 of Rsqrt (shared with RsqrtTable): (x > 0 mask, mantissa m_raw in UQ(0, M), exponent e) with
    x 2^-fi = m_raw 2^-M 2^(2e) and m_raw in [2^(M-2), 2^M) (x <= 0 is treated as x = 1)."""
    positive = x > 0
    xs = x if positive.all() else np.where(positive, x, 1)
    n = _bit_length(xs)
    k = n + ((n - fi) & 1)
    if k_max <= M:                 # no input has k > M: m = x << (M - k) < 2^M, exact
        m = xs << (M - k)
    else:
        left = np.maximum(M - k, 0)
        right = np.maximum(k - M, 0)
        m = ((xs << left) + ((1 << right) >> 1)) >> right   # exact left shift or shift_round right
        m = np.minimum(m, (1 << M) - 1)
    e = (k - fi) >> 1                                        # exact: k - fi is even
    return positive, m, e


def _rsqrt_denormalise(positive, y, e, Y: int, out: Shape, s_max: int, sat, name: str) -> np.ndarray:
    """Step 5 of Rsqrt (shared with RsqrtTable): raw_out = shift_round(y, Y + e - fo) for y in UQ(2, Y)
    (y > 2^(Y-1)), a left shift when Y + e - fo < 0, saturated into `out` (counted under `name`); x <= 0
    gives the maximum, counted. `s_max` bounds the shift Y + e - fo from above."""
    s = e + (Y - out.f)
    if s.size and s.min() >= 0:                # the common case: right shifts only
        # y < 2^(Y+2): a shift beyond Y + 3 (up to 62, no int64 overflow) still gives 0, as the clamp does
        rs = s if s_max <= 62 else np.minimum(s, Y + 3)
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
    return out.saturate(res, sat, name)



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
            raise FormatError(f"Rsqrt: the internal mantissa (out_shape {out_shape} width + guard_bits = "
                             f"{self.M} bits) is narrower than seed_bits = {self.seed_bits}")
        if in_shape.max_raw < 1:
            raise FormatError(f"Rsqrt in_shape {in_shape} has no positive values")
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
        M, Y = self.M, self.Y
        positive, m, e = _rsqrt_normalise(x, M, self.in_shape.f, self.k_max)    # 2. normalise
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
        return _rsqrt_denormalise(positive, y, e, self.Y, self.out_shape, self._s_max, sat, self.name)   # 5.

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


class RsqrtTable:
    """Reciprocal square root y = 1/sqrt(v) by table and linear interpolation, bit-true: one product and
    one ROM instead of Rsqrt's Newton step (three products).

    Input raw x in `in_shape` (value v = x 2^-fi), output raw in `out_shape` (fo = out_shape.f). Internal
    mantissa width M = out_shape.width + guard_bits, iterate y with Y = M fraction bits, S = segments_log2,
    F = M - S (M >= S + 1). All integers are non-negative in steps 2-4.

    1. Non-positive input: x <= 0 gives the out_shape maximum, one saturation counted per element.
    2. Normalise exactly as Rsqrt (its step 2): mant = x 2^-k in [1/4, 1) with k - fi even (the input
       scaled into [1, 4) by an even shift, then divided by 4), held as m_raw in UQ(0, M) (rounded only
       when k > M, with Rsqrt's clamp); e = (k - fi) / 2. Write m = m_raw 2^-M.
    3. Segment. The octaves [1/4, 1/2) (o = 0) and [1/2, 1) (o = 1) have 2^(S-1) segments each, of width
       h_o = 2^-(S+1-o) (the same width relative to m, so the same relative error in both):
         o    = m_raw >> (M - 1)                   (m_raw's top bit)
         j    = the S - 1 bits below m_raw's leading one (bits M-2..M-S if o = 1, M-3..M-S-1 if o = 0)
         frac = the bits below those, as a fraction of the segment in UQ(0, F): m_raw mod 2^F if o = 1,
                (m_raw mod 2^(F-1)) << 1 if o = 0, so that m = a + t h_o exactly, t = frac 2^-F
       and the ROM address addr = o 2^(S-1) + j (2^S words).
    4. Interpolate: y = c0[addr] - shift_round(frac * sl[addr], F) in UQ(2, Y), i.e. c0 - sl t with the
       product rounded to nearest (ties up): one product of F x bits(sl) bits, formed exactly (as Rsqrt's,
       `_mul_shift_round`) and rounded once.
    5. Denormalise and saturate exactly as Rsqrt (its step 5): raw_out = shift_round(y, Y + e - fo).

    Table (construction time). Segment j of octave o starts at a = (2^(S-1) + j) h_o; on it write
    g(t) = 2^Y / sqrt(a + t h_o), t in [0, 1] (1/sqrt in units of 2^-Y: convex, decreasing).
    - slope sl = round(g(0) - g(1)), an integer >= 0: the chord's drop, rounded;
    - the line c0 - sl t minus g is concave in t: with r(t) = -sl t - g(t) its minimum r_min is at an end
      (t = 0 or 1), its maximum r_max at t* where g'(t*) = -sl, i.e. a + t* h_o = (2 sl / (2^Y h_o))^(-2/3)
      (clamped into [0, 1]);
    - offset c0 = round(-(r_max + r_min) / 2), clamped into [2^Y, 2^(Y+1) - 1] (the ROM holds c0 - 2^Y in
      Y bits; only the first segment, a = 1/4 where g(0) = 2^(Y+1), can round up to 2^(Y+1), and the clamp
      moves it by 1 where f > 1.99): the line is centred on the curve, its error as large above as below
      (minimax: half the chord's worst error; its mean over a segment is +1/6 of the chord's gap, a bias of
      about E_tab / 10 where the rounding terms dominate, measured).
    ROM word: c0 - 2^Y (Y bits) and sl (about Y + 1 - S bits): 22 + 13 = 35 bits for an 18-bit output
    with the default guard_bits = 4 (1,024 words, two 1024 x 18 block RAMs).

    Error bound (`internal_relative_error_bound`, `error_bound`, `max_relative_error_bound`), in units of
    2^-Y on y:
    - the line: |c0 - sl t - g(t)| <= e_j := max(|c0 + r_min|, |c0 + r_max|) <= (r_max - r_min) / 2 + 1/2
      (c0's rounding; + 1 on the clamped word). For the exact chord slope, r_max - r_min is the chord's
      largest gap, at most 2^Y h_o^2 max|f''| / 8 (f = 1/sqrt, f''(m) = 3/4 m^-5/2); the rounded slope
      moves r by at most t / 2 <= 1/2. So e_j <= 2^Y h_o^2 max|f''| / 16 + 3/4;
    - the interpolation's rounding: + 1/2;
    - relative to 2^Y f(m) >= 2^Y f(a + h_o), with max|f''| = f''(a) on the segment:
      h_o^2 f''(a) / (16 f(a + h_o)) = 3/64 (h_o/a)^2 (1 + h_o/a)^(1/2), h_o / a <= 2^(1-S) in both octaves
      (a >= 2^(S-1) h_o), and f >= 1, so
        E_tab = max_j (e_j + 1/2) 2^-Y / f(a_j + h_o)
              <= (3/16) 2^-2S (1 + 2^(1-S))^(1/2) + (5/4) 2^-Y                     (a priori)
      i.e. h^2/16 max|f''| relative (half of h^2/8: the centred line) plus the roundings. S = 10, Y = 22
      (an 18-bit output): 1.79e-7 + 2.98e-7 = 4.8e-7 a priori, 3.53e-7 from the table (below 2^-21;
      the Newton step of the narrow preset, 9 seed bits: 7.6e-6). On the clamped word the rounding terms
      are 9/4 2^-Y / 1.99 < 5/4 2^-Y, within the same bound. `internal_relative_error_bound` takes e_j
      from the table itself (a float64 evaluation with a little slack), never above the a-priori value.
    - Mantissa rounding (only when an input can have k > M): as Rsqrt, eps_m = 1/sqrt(1 - 2^(1-M)) - 1.
    - Internal bound E_int = (1 + E_tab)(1 + eps_m) - 1 on |y 2^-Y 2^-e sqrt(v) - 1|; output bounds as
      Rsqrt: |out - 1/sqrt(v)| <= E_int / sqrt(v) + 2^-(fo+1) for every unsaturated output, and relative
      E_int + 2^-(fo+1) sqrt(v_max) over the input range.
    """


    def __init__(self, in_shape: Shape, out_shape: Shape, segments_log2: int = 10, guard_bits: int = 4,
                 name: str = "rsqrt"):
        self.in_shape = _check_shape("RsqrtTable in_shape", in_shape)
        self.out_shape = _check_shape("RsqrtTable out_shape", out_shape)
        self.S = _check_int("RsqrtTable segments_log2", segments_log2, 2, 12)
        self.guard_bits = _check_int("RsqrtTable guard_bits", guard_bits, 0, 8)
        self.name = str(name)
        self.M = self.Y = out_shape.width + self.guard_bits
        S, M, Y = self.S, self.M, self.Y
        if M < S + 1:
            raise FormatError(f"RsqrtTable: the internal mantissa (out_shape {out_shape} width + guard_bits = "
                              f"{M} bits) needs at least segments_log2 + 1 = {S + 1} bits")
        if in_shape.max_raw < 1:
            raise FormatError(f"RsqrtTable in_shape {in_shape} has no positive values")
        self.F = M - S
        # segment starts a = n 2^-q (n = 2^(S-1) + j, q = S + 1 - o) and ends (n + 1) 2^-q, exact in float64
        addr = np.arange(1 << S)
        o = addr >> (S - 1)
        n = ((1 << (S - 1)) + (addr & ((1 << (S - 1)) - 1))).astype(np.float64)
        h = np.ldexp(1.0, -(S + 1 - o))
        a = n * h
        g0, g1 = 2.0 ** Y / np.sqrt(a), 2.0 ** Y / np.sqrt(a + h)
        sl = np.floor(g0 - g1 + 0.5)
        # stationary point of r(t) = -sl t - g(t): (a + t h)^(-3/2) = 2 sl / (2^Y h)
        with np.errstate(divide="ignore"):
            ts = ((2.0 * sl / (2.0 ** Y * h)) ** (-2.0 / 3.0) - a) / h
        ts = np.clip(np.nan_to_num(ts, nan=1.0, posinf=1.0), 0.0, 1.0)
        r = lambda t: -sl * t - 2.0 ** Y / np.sqrt(a + t * h)
        r_min, r_max = np.minimum(r(0.0), r(1.0)), r(ts)
        # clamped into [2^Y, 2^(Y+1)) (the ROM holds c0 - 2^Y in Y bits): only the first segment (a = 1/4,
        # g(0) = 2^(Y+1)) can round up to 2^(Y+1); the clamp moves it by 1, where f >= 1.99
        c0 = np.clip(np.floor(-(r_max + r_min) / 2 + 0.5), 2.0 ** Y, 2.0 ** (Y + 1) - 1)
        self.c0 = c0.astype(np.int64)
        self.slope = sl.astype(np.int64)
        # e_j, evaluated in float64 from values below 2^(Y+2) (ulp 2^(Y-51)): + 2^-10 + 2^(Y-44) units of slack
        self.seg_error = np.maximum(np.abs(c0 + r_min), np.abs(c0 + r_max)) + 2.0 ** -10 + 2.0 ** (Y - 44)
        self._seg_f_min = 1.0 / np.sqrt(a + h)                  # f(a + h_o), the smallest f on the segment
        self.k_max = int(in_shape.max_raw).bit_length() + 1
        self._s_max = Y - out_shape.f + (self.k_max - in_shape.f + 1) // 2
        self._bound = None

    # ---- the unit
    def _core(self, raw):
        """Steps 2-4: (x > 0 mask, y in UQ(2, Y), e) for raw inputs."""
        x = _check_raw(raw, self.in_shape, f"RsqrtTable({self.in_shape} -> {self.out_shape})")
        M, S, F = self.M, self.S, self.F
        positive, m, e = _rsqrt_normalise(x, M, self.in_shape.f, self.k_max)       # 2.
        o = m >> (M - 1)                                                            # 3.
        hi = o.astype(bool)
        addr = np.where(hi, m >> (M - S), (m >> (M - S - 1)) - (1 << (S - 1)))
        frac = np.where(hi, m & ((1 << F) - 1), (m & ((1 << (F - 1)) - 1)) << 1)
        sl_bits = int(self.slope.max()).bit_length()
        y = self.c0[addr] - _mul_shift_round(frac, self.slope[addr], F, F + sl_bits, sl_bits)  # 4.
        return positive, y, e

    def internal(self, raw: np.ndarray) -> np.ndarray:
        """The result before the output rounding, y 2^-Y 2^-e, as float64 (nan where x <= 0)."""
        positive, y, e = self._core(raw)
        val = np.ldexp(y.astype(np.float64), (-self.Y - e).astype(np.int32))
        return np.where(positive, val, np.nan)

    def __call__(self, raw: np.ndarray, sat: Saturations | None = None) -> np.ndarray:
        positive, y, e = self._core(raw)
        return _rsqrt_denormalise(positive, y, e, self.Y, self.out_shape, self._s_max, sat, self.name)   # 5.

    # ---- references and bounds
    reference = staticmethod(Rsqrt.reference)

    def table_relative_error(self) -> float:
        """E_tab: the largest relative error of y 2^-Y against 1/sqrt(m) over all segments (line, its
        offset's rounding and the interpolation's rounding), from the table itself."""
        return float(np.max((self.seg_error + 0.5) * 2.0 ** -self.Y / self._seg_f_min))

    def a_priori_table_error(self) -> float:
        """The docstring's bound on E_tab from S and Y alone: (3/16) 2^-2S (1 + 2^(1-S))^(1/2) + (5/4) 2^-Y."""
        S = self.S
        return 3 / 16 * 2.0 ** (-2 * S) * math.sqrt(1 + 2.0 ** (1 - S)) + 1.25 * 2.0 ** -self.Y

    def internal_relative_error_bound(self) -> float:
        """E_int: bound on the relative error of y 2^-Y 2^-e before the output rounding."""
        if self._bound is None:
            E = self.table_relative_error()
            eps_m = 1 / math.sqrt(1 - 2.0 ** (1 - self.M)) - 1 if self.k_max > self.M else 0.0
            self._bound = (1 + E) * (1 + eps_m) - 1 if eps_m else E
        return self._bound

    def error_bound(self, value) -> np.ndarray:
        """Bound on |out - 1/sqrt(value)| (real units) for inputs whose output does not saturate."""
        return self.internal_relative_error_bound() * self.reference(value) + 0.5 * self.out_shape.lsb

    def max_relative_error_bound(self) -> float:
        """Bound on |out sqrt(v) - 1| over every positive input whose output does not saturate."""
        return self.internal_relative_error_bound() + 0.5 * self.out_shape.lsb * math.sqrt(self.in_shape.max_value)

    def to_dict(self) -> dict:
        return {"unit": "rsqrt_table", "name": self.name, "in": str(self.in_shape), "out": str(self.out_shape),
                "segments_log2": self.S, "guard_bits": self.guard_bits, "mantissa_bits": self.M,
                "rom_words": len(self.c0), "rom_word_bits": self.Y + int(self.slope.max()).bit_length(),
                "internal_relative_error_bound": self.internal_relative_error_bound(),
                "max_relative_error_bound": self.max_relative_error_bound()}


# ----------------------------------------------------------------------------------- inverse tables

@dataclass(frozen=True)
class OddCurve:
    """A strictly increasing odd function y = g(t), convex on [t_lo, t_hi] (t_lo >= 0), with companions.

    `g`, `dg`, `d2g` evaluate g and its first two derivatives on t in [t_lo, t_hi] (float64 arrays).
    `companions`: functions c(t) tabulated beside the inverse, each as (c, dc, d2c); the table then also
    gives c(g^-1(y)) (the damper's rate beside its force). `input`: the quantity of y; `outputs`: the
    quantity of each output, the inverse first. Outside [g(t_lo), g(t_hi)] the curve is linear; the datapath handles those pieces.
    """
    name: str
    input: str
    g: Callable
    dg: Callable
    d2g: Callable
    t_lo: float
    t_hi: float
    outputs: tuple
    companions: tuple = ()


def solve_increasing(g: Callable, y: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """t in [lo, hi] with g(t) = y for a strictly increasing g, by bisection to float64 resolution."""
    y = np.asarray(y, np.float64)
    a, b = np.full(y.shape, float(lo)), np.full(y.shape, float(hi))
    for _ in range(1100):                   # halves the bracket until it is one float apart
        m = 0.5 * (a + b)
        if not np.any((m > a) & (m < b)):
            break
        right = g(m) < y
        a, b = np.where(right, m, a), np.where(right, b, m)
    return np.where(np.abs(g(a) - y) <= np.abs(g(b) - y), a, b)


class InverseTable:
    """The inverse t = g^-1(y) of a strictly increasing odd curve (and functions of t beside it) by table
    and linear interpolation over the curve's nonlinear piece [y1, y2] = [g(t_lo), g(t_hi)], bit-true.

    The model of MODEL.md section 2 v2 needs two: Phi = G^-1 (the element's tension from its drive, with the
    damper's rate beside it) and Psi = H^-1 (the damper's force from its rate, on the a_min stop).

    Input: raw y >= 0 (the magnitude; the datapath applies the sign and the linear pieces outside [y1, y2])
    in `in_shape` (fy = in_shape.f fraction bits). Outputs: one raw value per entry of `out_shapes` (the
    inverse, then the companions). S = segments_log2, P = frac_bits.

    Constants (construction time, exact rational arithmetic where it matters):
    - comparator thresholds Y1 = floor(y1 2^fy) (clipped to in_shape.max_raw) and Y2 = ceil(y2 2^fy)
      (clipped to in_shape.max_raw + 1);
    - K = 2^S / (y2 - y1) (segments per input unit) as an unsigned operand of scale_bits significant bits,
      rounded to nearest: K_raw in [2^(scale_bits-1), 2^scale_bits], K_q = K_raw 2^-kf;
    - the offset OFF = round(y1 2^fy K_raw), an integer in the units of the product y_raw K_raw;
    - tables of 2^S + 1 entries at the breakpoints y_j = y1 + j (y2 - y1) / 2^S: t_j = g^-1(y_j) solved by
      bisection to float64 resolution (`solve_increasing`), and each output at t_j, rounded to nearest into
      its format. An entry that does not fit is clamped and flagged: an item that uses a flagged entry
      counts one saturation per output.

    Per item (integers; fraction bits in brackets):
    1. y_raw <= Y1: pos = 0 (the first entry). y_raw >= Y2: the end point, idx = 2^S - 1, frac = 2^P.
    2. Otherwise D = y_raw K_raw - OFF [fy + kf] (>= 0 where used) and pos = shift_round(D, fy + kf - P) [P]
       (a left shift when fy + kf - P < 0), limited to the end point 2^(S+P).
    3. idx = pos >> P, frac = pos & (2^P - 1) (the end point: idx = 2^S - 1, frac = 2^P).
    4. out = tab[idx] + shift_round(frac (tab[idx+1] - tab[idx]), P) for every table; between two entries,
       so it always fits.

    Error bound (`error_bounds()`, real units, items on [y1, y2] that use no clamped entry), per output o:
    - position: the unit interpolates at y_eff = y1 + h pos 2^-P, h = (y2 - y1) / 2^S, with
      |y_eff - y| <= dy = (y2 - y1)|K_q/K - 1| + h 2^-P (|OFF - y1 2^fy K_raw| 2^-(fy+kf-P) + 1/2 if step 2
      rounds) (`position_error_bound()`);
    - interpolation of exact breakpoint values: h^2/8 max|o''| on each segment, with o'' = -g''/g'^3 for
      the inverse and (c'' g' - c' g'')/g'^3 for a companion c (t = g^-1(y)), maximised over 17 points
      of every segment and taken 5 % higher (the curves are smooth on [t_lo, t_hi]);
    - o is Lipschitz with L = max|o'| (o' = 1/g' or c'/g', the same sampling): + L dy;
    - table rounding (1/2 LSB) plus the interpolation rounding (1/2 LSB): + 1 LSB of the output.
    """

    SAMPLES_PER_SEGMENT = 17
    SAMPLING_MARGIN = 1.05

    def __init__(self, in_shape: Shape, out_shapes, curve: OddCurve, segments_log2: int = 8,
                 frac_bits: int = 16, scale_bits: int = 25, name: str | None = None):
        self.in_shape = _check_shape("InverseTable in_shape", in_shape)
        if not isinstance(curve, OddCurve):
            raise FormatError(f"InverseTable needs an OddCurve, got {curve!r}")
        out_shapes = tuple(out_shapes)
        if len(out_shapes) != 1 + len(curve.companions):
            raise FormatError(f"InverseTable: {len(out_shapes)} output formats for 1 inverse and "
                             f"{len(curve.companions)} companions")
        self.out_shapes = tuple(_check_shape(f"InverseTable output {k}", s) for k, s in enumerate(out_shapes))
        self.S = _check_int("InverseTable segments_log2", segments_log2, 1, 12)
        self.P = _check_int("InverseTable frac_bits", frac_bits, 1, 24)
        self.scale_bits = _check_int("InverseTable scale_bits", scale_bits, 8, 29)
        self.curve = curve
        self.name = str(curve.name if name is None else name)
        t_lo, t_hi = _check_real("InverseTable t_lo", curve.t_lo), _check_real("InverseTable t_hi", curve.t_hi)
        if not 0 <= t_lo < t_hi:
            raise FormatError(f"InverseTable: need 0 <= t_lo < t_hi, got t_lo = {t_lo:g}, t_hi = {t_hi:g}")
        y1, y2 = float(curve.g(np.float64(t_lo))), float(curve.g(np.float64(t_hi)))
        if not (math.isfinite(y1) and math.isfinite(y2) and 0 <= y1 < y2):
            raise FormatError(f"InverseTable: the curve must increase on [t_lo, t_hi], got g = {y1:g} .. {y2:g}")
        if y2 - y1 < in_shape.lsb:
            raise FormatError(f"InverseTable: y2 - y1 = {y2 - y1:g} is below one LSB ({in_shape.lsb:g}) of "
                             f"in_shape {in_shape}; the nonlinear piece cannot be resolved")
        self.t_lo, self.t_hi, self.y1, self.y2 = t_lo, t_hi, y1, y2
        S, P, sb, fy = self.S, self.P, self.scale_bits, in_shape.f
        Y1x, Y2x = Fraction(y1) * Fraction(2) ** fy, Fraction(y2) * Fraction(2) ** fy   # exact
        self.Y1 = min(math.floor(Y1x), in_shape.max_raw)
        self.Y2 = min(math.ceil(Y2x), in_shape.max_raw + 1)
        K = Fraction(2 ** S) / (Fraction(y2) - Fraction(y1))
        ex = K.numerator.bit_length() - K.denominator.bit_length()      # 2^(ex-1) <= K < 2^(ex+1)
        if K >= Fraction(2) ** ex:
            ex += 1                                                     # now 2^(ex-1) <= K < 2^ex
        self.kf = sb - ex
        self.K_raw = math.floor(K * Fraction(2) ** self.kf + Fraction(1, 2))
        self.K_q = self.K_raw * 2.0 ** -self.kf
        self.K_rel_error = float(abs(Fraction(self.K_raw) * Fraction(2) ** -self.kf / K - 1))
        self.pos_shift = fy + self.kf - P
        if self.Y1 < in_shape.max_raw:                  # the interpolated piece is reachable
            off = Y1x * self.K_raw
            self.OFF = math.floor(off + Fraction(1, 2))
            self.OFF_error = float(abs(self.OFF - off))
        else:
            self.OFF, self.OFF_error = 0, 0.0
        # breakpoints and their exact inverse
        j = np.arange((1 << S) + 1, dtype=np.float64)
        self.breakpoints = y1 + j * (y2 - y1) / (1 << S)
        t = solve_increasing(curve.g, self.breakpoints, t_lo, t_hi)
        t[0], t[-1] = t_lo, t_hi
        self.t_breakpoints = t
        self.tabs, self.clips = [], []
        for values, shape in zip(self._outputs(t), self.out_shapes):
            raw = _round_raw(values, shape.f)
            self.clips.append((raw < shape.min_raw) | (raw > shape.max_raw))
            self.tabs.append(np.clip(raw, shape.min_raw, shape.max_raw))
        # tab[j + 1] - tab[j], precomputed (exact integers): one lookup instead of two
        self._slopes = [np.diff(tab) for tab in self.tabs]
        self._bounds = None

    def _outputs(self, t):
        return [np.asarray(t, np.float64)] + [c(t) for c, _, _ in self.curve.companions]

    # ---- the unit
    def __call__(self, y_raw: np.ndarray, sat: Saturations | None = None):
        y = _check_raw(y_raw, self.in_shape, f"InverseTable {self.name}({self.in_shape})")
        if y.size and int(y.min()) < 0:
            raise FormatError(f"InverseTable {self.name}: inputs are magnitudes (>= 0)")
        S, P = self.S, self.P
        cap = 1 << (S + P)
        high = y >= self.Y2                                      # 1. the ends
        D = np.maximum(y * self.K_raw - self.OFF, 0)             # 2. (>= 0 wherever it is used)
        s = self.pos_shift
        if s > 0:
            pos = np.minimum(_shift_round_owned(D, min(s, 62)), cap)    # D < 2^61: shifts >= 62 give 0
        else:
            lim = 1 << max(S + P + s, 0)                         # D << -s >= cap iff D >= lim
            pos = np.where(D >= lim, cap, np.minimum(D, lim) << -s)
        if self.Y1 < self.in_shape.max_raw:
            # y <= Y1 already has D = 0, so pos = 0: y K_raw <= Y1x K_raw < OFF + 1/2 (Y1 <= Y1x)
            pos = np.where(high, cap, pos)
        else:
            pos = np.where(y <= self.Y1, 0, np.where(high, cap, pos))
        idx = np.minimum(pos >> P, (1 << S) - 1)                 # 3. (pos <= cap: the end point gives
        frac = pos - (idx << P)                                  #     idx = 2^S - 1, frac = 2^P)
        return tuple(self._interp(tab, slope, clip, idx, frac, sat)             # 4.
                     for tab, slope, clip in zip(self.tabs, self._slopes, self.clips))

    def _interp(self, tab, slope, clipped, idx, frac, sat):
        """tab[idx] + shift_round(frac (tab[idx + 1] - tab[idx]), P), with slope[idx] = tab[idx + 1] - tab[idx]."""
        if sat is not None and clipped.any():
            n = int(np.count_nonzero(clipped[idx] | (clipped[idx + 1] & (frac > 0))))
            if n:
                sat.add(self.name, n)
        return tab[idx] + _shift_round_owned(frac * slope[idx], self.P)

    # ---- references and bounds
    def reference(self, y) -> list:
        """The outputs at real inputs y, clamped into [y1, y2] (as the unit), float64, exact."""
        y = np.clip(np.asarray(y, np.float64), self.y1, self.y2)
        return self._outputs(solve_increasing(self.curve.g, y, self.t_lo, self.t_hi))

    def position_error_bound(self) -> float:
        """dy: bound on |y_eff - y| (input units) for the point at which the tables are interpolated."""
        h = (self.y2 - self.y1) / (1 << self.S)
        rounding = self.OFF_error * 2.0 ** -self.pos_shift + (0.5 if self.pos_shift > 0 else 0.0)
        return (self.y2 - self.y1) * self.K_rel_error + h * 2.0 ** -self.P * rounding

    def derivatives(self, t):
        """(o', o'') of every output with respect to y, at t = g^-1(y)."""
        cv = self.curve
        g1, g2 = cv.dg(t), cv.d2g(t)
        out = [(1.0 / g1, -g2 / g1 ** 3)]
        for _, dc, d2c in cv.companions:
            c1, c2 = dc(t), d2c(t)
            out.append((c1 / g1, (c2 * g1 - c1 * g2) / g1 ** 3))
        return out

    def error_bounds(self) -> dict:
        """Bounds on |output - reference| per output (by index), in real units, and their parts."""
        if self._bounds is None:
            n = self.SAMPLES_PER_SEGMENT
            tb = self.t_breakpoints
            frac = np.linspace(0.0, 1.0, n)
            t = (tb[:-1, None] + (tb[1:] - tb[:-1])[:, None] * frac[None, :])       # (2^S, n)
            h = (self.y2 - self.y1) / (1 << self.S)
            dy = self.position_error_bound()
            bounds = []
            for (d1, d2), shape in zip(self.derivatives(t), self.out_shapes):
                lip = float(np.max(np.abs(d1))) * self.SAMPLING_MARGIN
                interp = h * h / 8 * float(np.max(np.abs(d2))) * self.SAMPLING_MARGIN
                bounds.append({"total": interp + lip * dy + shape.lsb, "interp": interp,
                               "lipschitz": lip, "position": dy})
            self._bounds = bounds
        return self._bounds

    def to_dict(self) -> dict:
        return {"unit": "inverse_table", "name": self.name, "in": str(self.in_shape),
                "out": [str(s) for s in self.out_shapes], "outputs": list(self.curve.outputs),
                "segments_log2": self.S, "frac_bits": self.P, "scale_bits": self.scale_bits,
                "K_raw": self.K_raw, "K_frac_bits": self.kf, "OFF": self.OFF, "Y1": self.Y1, "Y2": self.Y2,
                "y1": self.y1, "y2": self.y2,
                "clipped_entries": int(sum(int(c.sum()) for c in self.clips)),
                "error_bounds": [b["total"] for b in self.error_bounds()]}
