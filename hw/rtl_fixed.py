"""Fixed-point values for Amaranth: a raw Amaranth value plus its format, with exact arithmetic.

Names follow Amaranth's proposed `lib.fixed` (RFC 41): formats are the `SQ(i, f)` / `UQ(i, f)` shapes of
hw/fixed.py (one definition for the bit-true model and the hardware), `Const` makes a constant, `reshape`
moves the binary point exactly, `round` rounds to nearest (ties up) into a format and `saturate` clamps
into it, returning the flag the saturation counters count; `as_float` reads a raw value back.

Arithmetic is exact: a product has i1 + i2 integer and f1 + f2 fraction bits, a sum aligns both operands
to the finer binary point and grows by one bit. Rounding and saturation happen only where asked, which is
where the bit-true model (hw/fixed.py) rounds and saturates, so the two agree bit for bit.
"""
from __future__ import annotations

from amaranth.hdl import Cat, Mux, Value, signed, unsigned
from amaranth.hdl import Const as _AConst

from .fixed import SQ, UQ, Shape

__all__ = ["SQ", "UQ", "Shape", "FixedValue", "Const", "as_shape", "as_float"]


def as_shape(fmt: Shape):
    """The Amaranth shape holding the raw integers of `fmt`."""
    return signed(fmt.width) if fmt.signed else unsigned(fmt.width)


def as_float(fmt: Shape, raw: int) -> float:
    return float(raw) * fmt.lsb


class FixedValue:
    """An Amaranth value `raw` holding a fixed-point number with `f` fraction bits (value = raw 2^-f).

    Intermediate results keep whatever width their exact arithmetic needs; `round` and `saturate` bring
    them into a format (a `Shape`) again.
    """

    def __init__(self, raw, f: int):
        self.raw = Value.cast(raw)
        self.f = int(f)

    @classmethod
    def of(cls, shape: Shape, raw) -> "FixedValue":
        if not isinstance(shape, Shape):
            raise TypeError(f"FixedValue needs a fixed-point Shape (SQ/UQ), got {shape!r}")
        raw = Value.cast(raw)
        if raw.shape().signed != shape.signed:
            raw = raw.as_signed() if shape.signed else raw.as_unsigned()
        return cls(raw, shape.f)

    def __repr__(self):
        return f"FixedValue({self.raw!r}, f={self.f})"

    # ---- exact arithmetic (Amaranth widens the raw values as needed)
    def __mul__(self, other: "FixedValue") -> "FixedValue":
        return FixedValue(self.raw * other.raw, self.f + other.f)

    def _aligned(self, other):
        f = max(self.f, other.f)
        return self.reshape(f).raw, other.reshape(f).raw, f

    def __add__(self, other: "FixedValue") -> "FixedValue":
        a, b, f = self._aligned(other)
        return FixedValue(a + b, f)

    def __sub__(self, other: "FixedValue") -> "FixedValue":
        a, b, f = self._aligned(other)
        return FixedValue(_signed(a) - _signed(b), f)

    def __neg__(self) -> "FixedValue":
        return FixedValue(-_signed(self.raw), self.f)

    def __lt__(self, other: "FixedValue") -> Value:
        a, b, _ = self._aligned(other)
        return a < b

    def __le__(self, other: "FixedValue") -> Value:
        a, b, _ = self._aligned(other)
        return a <= b

    # ---- format changes
    def reshape(self, f: int) -> "FixedValue":
        """The same value with f fraction bits; only exact moves (f >= self.f) are allowed."""
        if f < self.f:
            raise ValueError(f"reshape from {self.f} to {f} fraction bits would drop bits: use round()")
        return FixedValue(self.raw.shift_left(f - self.f), f)

    def round(self, dst: Shape) -> tuple["FixedValue", Value]:
        """Round to nearest (ties up) to dst's binary point, then saturate into dst: (value, saturated)."""
        s = self.f - dst.f
        raw = self.raw
        if s > 0:
            raw = (raw + (1 << (s - 1))) >> s
        elif s < 0:
            raw = raw.shift_left(-s)
        return FixedValue(raw, dst.f).saturate(dst)

    def saturate(self, dst: Shape) -> tuple["FixedValue", Value]:
        """Clamp into dst (same binary point required): (value, saturated flag)."""
        if dst.f != self.f:
            raise ValueError(f"saturate needs the same binary point ({self.f} -> {dst}): use round()")
        raw = self.raw
        over, under = raw > dst.max_raw, raw < dst.min_raw
        clamped = Mux(over, dst.max_raw, Mux(under, dst.min_raw, raw))
        return FixedValue.of(dst, clamped[:dst.width]), over | under


def _signed(v: Value) -> Value:
    """v as a signed value of the same numeric value (unsigned values gain a zero sign bit)."""
    return v if v.shape().signed else Cat(v, _AConst(0, 1)).as_signed()


def Const(value: float, shape: Shape) -> tuple[FixedValue, int]:
    """A constant: value rounded to nearest into `shape` and saturated; returns (value, saturations)."""
    from .fixed import Saturations
    sat = Saturations()
    raw = int(shape.from_float(value, sat, "const"))
    return FixedValue.of(shape, _AConst(raw, as_shape(shape))), sat.total
