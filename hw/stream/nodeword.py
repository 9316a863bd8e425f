"""How a node's state packs into memory words, and small gateware helpers the components share.

A node word holds x_0 .. x_{D-1}, u_0 .. u_{D-1} (raw, in the formats of "x" and "u"), each in a
field of `field_bits` = the wider of the two formats, so that the host can write one field (one
segment of the node store). A group word is Q node words, node q of the group at bits
[q * bits, (q + 1) * bits).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from amaranth.hdl import Array, Cat, Const, Signal

from ..rtl_fixed import as_shape


@dataclass(frozen=True)
class NodeWord:
    dim: int
    x_shape: object        # hw.fixed.Shape of "x"
    u_shape: object        # hw.fixed.Shape of "u"

    @classmethod
    def of(cls, formats, dim: int) -> "NodeWord":
        return cls(dim, formats["x"], formats["u"])

    @property
    def fields(self) -> int:
        return 2 * self.dim

    @property
    def field_bits(self) -> int:
        return max(self.x_shape.width, self.u_shape.width)

    @property
    def bits(self) -> int:
        return self.fields * self.field_bits

    def field_shape(self, f: int):
        return self.x_shape if f < self.dim else self.u_shape

    def unpack(self, word):
        """(X, U): lists of D raw values (Amaranth, signed like their formats) of a node word."""
        fb = self.field_bits
        vals = []
        for f in range(self.fields):
            shape = as_shape(self.field_shape(f))
            raw = word[f * fb:f * fb + shape.width]
            vals.append(raw.as_signed() if shape.signed else raw)
        return vals[:self.dim], vals[self.dim:]

    def pack(self, X, U):
        fb = self.field_bits
        return Cat(*[Cat(v, Const(0, fb - len(v))) for v in list(X) + list(U)])

    def pack_int(self, X, U) -> int:
        """The node word of raw integers (Python)."""
        fb = self.field_bits
        w = 0
        for f, v in enumerate(list(X) + list(U)):
            w |= (int(v) & ((1 << fb) - 1)) << (f * fb)
        return w

    def unpack_int(self, word: int):
        fb = self.field_bits
        out = []
        for f in range(self.fields):
            width = self.field_shape(f).width
            v = (int(word) >> (f * fb)) & ((1 << width) - 1)
            out.append(v - (1 << width) if self.field_shape(f).signed and v >> (width - 1) else v)
        return out[:self.dim], out[self.dim:]


def bits_for(count: int) -> int:
    """Bits of an index into `count` things (at least 1)."""
    return max(1, int(count - 1).bit_length())


def delay(m, value, cycles: int, name: str, *, data: bool = False):
    """`value` `cycles` cycles later (a chain of registers). `data`: a data word, whose registers have no
    reset, as a pipeline's values have none (hw/pipeline.py): whoever uses it qualifies it with a valid
    bit, a strobe or a state that does."""
    for k in range(cycles):
        r = Signal.like(value, name=f"{name}_d{k + 1}", **({"reset_less": True} if data else {}))
        m.d.sync += r.eq(value)
        value = r
    return value


def segment(value, index, width: int, count: int):
    """Part `index` (an Amaranth value or int) of `value`, made of `count` parts of `width` bits: a
    multiplexer (not a shift by index * width, in which Yosys may see a multiplier)."""
    if isinstance(index, int):
        return value[index * width:(index + 1) * width]
    if count == 1:
        return value[:width]
    return Array([value[k * width:(k + 1) * width] for k in range(count)])[index]


def split_words(value, count: int, shape):
    """`count` words of Amaranth shape `shape` packed in `value` (word k at bits k w .. (k + 1) w - 1), each
    read as its shape reads it (signed or not)."""
    w = shape.width
    return [value[k * w:(k + 1) * w].as_signed() if shape.signed else value[k * w:(k + 1) * w]
            for k in range(count)]


def pack_ints(values, width: int) -> int:
    """Raw integers into one word, value k at bits k width .. (k + 1) width - 1 (two's complement)."""
    w = 0
    for k, v in enumerate(values):
        w |= (int(v) & ((1 << width) - 1)) << (k * width)
    return w


def unpack_ints(word: int, count: int, width: int, signed: bool = True) -> list[int]:
    """The inverse of pack_ints."""
    out = []
    for k in range(count):
        v = (int(word) >> (k * width)) & ((1 << width) - 1)
        out.append(v - (1 << width) if signed and v >> (width - 1) else v)
    return out
