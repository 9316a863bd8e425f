"""Fixed-point number formats and their bit-exact arithmetic on NumPy int64 arrays.

A format is a shape `SQ(i, f)` (signed, two's complement) or `UQ(i, f)` (unsigned): i integer bits
(including the sign bit for SQ), f fraction bits, width i + f; the value of a raw integer r is r * 2^-f.
Names follow Amaranth's proposed `lib.fixed` (RFC 41). `i` may be negative or exceed the width's
natural range: a format is just a width and the position of the binary point.

Every operation here is what the hardware does, bit for bit:
- products are exact (both operands are at most 32 bits, so a product fits in int64), then
- rescaled to the destination format with **round to nearest, ties up**: (p + 2^(s-1)) >> s
  (an arithmetic shift; never a truncation of a state update), then
- **saturated** to the destination's range; every saturation is counted per quantity (never a wrap).
Sums align both operands to the finer binary point (exact left shifts), add, then rescale.
"""
from __future__ import annotations

import functools
from collections import Counter
from dataclasses import dataclass

import numpy as np

from golden.errors import RheoError


class FormatError(RheoError, ValueError):
    """Number formats under which the scene cannot run right (a constant or the initial state does not fit,
    a format wider than the bit-true model or a function unit supports)."""

MAX_OPERAND_BITS = 32


@dataclass(frozen=True)
class Shape:
    """A fixed-point format: signedness, integer bits i and fraction bits f."""
    signed: bool
    i: int
    f: int

    def __post_init__(self):
        if self.width < 1:
            raise FormatError(f"{self}: width must be at least 1 bit")
        if self.width > 62:
            raise FormatError(f"{self}: width {self.width} exceeds the 62 bits the bit-true model supports")

    @property
    def width(self) -> int:
        return self.i + self.f

    @property
    def min_raw(self) -> int:
        return -(1 << (self.width - 1)) if self.signed else 0

    @property
    def max_raw(self) -> int:
        return (1 << (self.width - 1)) - 1 if self.signed else (1 << self.width) - 1

    @property
    def lsb(self) -> float:
        return 2.0 ** -self.f

    @property
    def max_value(self) -> float:
        return self.max_raw * self.lsb

    @property
    def min_value(self) -> float:
        return self.min_raw * self.lsb

    def __str__(self) -> str:
        return f"{'SQ' if self.signed else 'UQ'}({self.i}, {self.f})"

    def to_dict(self) -> dict:
        return {"signed": self.signed, "i": self.i, "f": self.f, "width": self.width, "lsb": self.lsb}

    # ---- conversions
    def from_float(self, x, sat: "Saturations | None" = None, name: str = "") -> np.ndarray:
        """Round real values to the nearest raw integer (ties up) and saturate."""
        raw = np.floor(np.asarray(x, float) * 2.0 ** self.f + 0.5)
        raw = np.nan_to_num(raw, nan=0.0, posinf=float(self.max_raw), neginf=float(self.min_raw))
        return self.saturate(np.clip(raw, -2.0 ** 62, 2.0 ** 62).astype(np.int64), sat, name)

    def to_float(self, raw) -> np.ndarray:
        return np.asarray(raw, np.int64) * self.lsb

    def saturate(self, raw: np.ndarray, sat: "Saturations | None" = None, name: str = "") -> np.ndarray:
        raw = np.asarray(raw)
        if raw.size == 0:
            return raw
        lo, hi = self._bounds
        if raw.max() <= hi and raw.min() >= lo:       # the common case: nothing to clamp
            return raw
        if sat is not None:
            sat.add(name, int(np.count_nonzero((raw < lo) | (raw > hi))))
        return np.minimum(np.maximum(raw, lo), hi)

    @functools.cached_property
    def _bounds(self):
        return self.min_raw, self.max_raw


def SQ(i: int, f: int) -> Shape:
    return Shape(True, i, f)


def UQ(i: int, f: int) -> Shape:
    return Shape(False, i, f)


class Saturations(Counter):
    """Saturation counts per quantity name."""

    def add(self, name: str, n: int) -> None:
        self[name] += n

    @property
    def total(self) -> int:
        return int(sum(self.values()))


def shift_round(raw: np.ndarray, shift: int) -> np.ndarray:
    """raw * 2^-shift rounded to nearest (ties up) for shift > 0; exact left shift for shift <= 0."""
    if shift > 62:            # every int64 operand of this model is below 2^62 in magnitude: rounds to 0
        return np.zeros_like(raw)
    if shift > 0:
        return (raw + (1 << (shift - 1))) >> shift
    if shift < 0:
        return raw << (-shift)
    return raw


def _shift_round_owned(raw, shift: int):
    """shift_round(raw, shift), in place when raw is an array the caller owns (a fresh intermediate)."""
    if shift > 62:
        return np.zeros_like(raw)
    if shift > 0:
        raw += 1 << (shift - 1)
        raw >>= shift
    elif shift < 0:
        raw <<= -shift
    return raw


def _shift_left(raw, shift: int) -> np.ndarray:
    """raw << shift (shift >= 0) as int64, without a copy for shift 0: exact, to a finer binary point."""
    raw = np.asarray(raw, np.int64)
    return raw << shift if shift else raw


def round_into(raw, src_f: int, dst: Shape, sat=None, name="") -> np.ndarray:
    """A raw value with src_f fraction bits, rounded to nearest into dst and saturated."""
    return dst.saturate(shift_round(np.asarray(raw, np.int64), src_f - dst.f), sat, name)


def _round_owned_into(raw, src_f: int, dst: Shape, sat=None, name="") -> np.ndarray:
    """round_into for a fresh int64 intermediate the caller owns (rounded in place)."""
    return dst.saturate(_shift_round_owned(raw, src_f - dst.f), sat, name)


def rescale(raw, src: Shape, dst: Shape, sat=None, name="") -> np.ndarray:
    """Move a value from format src to format dst: round to nearest, then saturate."""
    return round_into(raw, src.f, dst, sat, name)


def mul(a, sa: Shape, b, sb: Shape, dst: Shape, sat=None, name="") -> np.ndarray:
    """Exact product of two operands, rounded and saturated into dst."""
    if sa.width > MAX_OPERAND_BITS or sb.width > MAX_OPERAND_BITS:
        raise FormatError(f"multiplier operands {sa} x {sb} exceed {MAX_OPERAND_BITS} bits")
    return _round_owned_into(np.asarray(a, np.int64) * np.asarray(b, np.int64), sa.f + sb.f, dst, sat, name)


def add(a, sa: Shape, b, sb: Shape, dst: Shape, sat=None, name="", subtract=False) -> np.ndarray:
    """a + b (or a - b), exact at the finer binary point, then rounded and saturated into dst."""
    f = max(sa.f, sb.f)
    a, b = _shift_left(a, f - sa.f), _shift_left(b, f - sb.f)
    return _round_owned_into(a - b if subtract else a + b, f, dst, sat, name)
