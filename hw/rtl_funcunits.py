"""Gateware for the bit-true function units of hw/funcunits.py: reciprocal square root and inverse table.

The units are Amaranth components built from an already-constructed NumPy model object, which is
their specification: every constant, ROM word, shift and rounding comes from the model, and for every
input the gateware's outputs (and saturation flags or counts) equal what the model computes, bit for bit.
`RsqrtUnit` implements `hw.funcunits.Rsqrt` (Newton), `RsqrtTableUnit` `hw.funcunits.RsqrtTable` (table
and interpolation, one multiplier); `InverseTableUnit` implements `hw.funcunits.InverseTable` (the damper's
Phi and Psi curves of MODEL.md section 2 v2, or any other odd curve's inverse).

All units are fully pipelined: they accept one input per clock cycle (initiation interval 1), never
stall (both streams are `always_ready`), and deliver the result of an input accepted in cycle c in cycle
c + `latency`; `o.valid` is `i.valid` delayed by `latency` cycles. Every product takes PRODUCT_LATENCY = 4
cycles (hw/rtl_fixed.py `pipelined_product`: 18x18 multipliers, or rows summed in logic for an operand of
at most 4 bits, each followed by a register, then the sum of the partial products in another register;
a multiplier's operands and its product registered beside it, hw/rtl_fixed.py DSP_REGS;
a product by a constant, the inverse table's scale K_raw, is shifts and adds, `constant_product`, when
they take few adders), and every rounding (a product plus 2^(s-1), then an arithmetic right shift by s) one more, so that no
cycle holds a multiplier and a wide adder. ROMs are
`amaranth.lib.memory.Memory` instances with synchronous read ports (block RAM) whose data is registered
before any arithmetic, or, with `tables` (hw/stream/tables.py), a read port of a ROM that another unit of
the same model shares (two ports of one block RAM, the same two cycles from address to registered word).
"""
from __future__ import annotations

from amaranth.hdl import Cat, Const, Module, Mux, Signal, Value, signed, unsigned
from amaranth.lib import data, stream, wiring
from amaranth.lib.memory import Memory
from amaranth.lib.wiring import In, Out

from .fixed import Shape
from .funcunits import InverseTable, Rsqrt, RsqrtTable
from .rtl_fixed import DSP_REGS, constant_product, registered_product

__all__ = ["RsqrtUnit", "RsqrtTableUnit", "InverseTableUnit", "PRODUCT_LATENCY"]

# cycles of every product in the units: a product wider than one 18x18 multiplier takes 2 (registered
# partial products, then their sum: hw/rtl_fixed.py `pipelined_product`) and DSP_REGS more (its operands
# and its product registered beside the multipliers: nextpnr had 3.2 ns of routing from a Psi table to its
# multiplier and 1.3 ns after it, 93 MHz); narrower ones are delayed to as many, so that a unit's latency
# does not depend on its formats
PRODUCT_LATENCY = 2 + DSP_REGS


def _raw_shape(shape: Shape):
    """The Amaranth shape of a fixed-point format's raw integer."""
    return signed(shape.width) if shape.signed else unsigned(shape.width)


def _bits(value: int) -> int:
    """Bits of an unsigned register that holds 0..value."""
    return max(int(value).bit_length(), 1)


def _signed_bits(lo: int, hi: int) -> int:
    """Bits of a signed register that holds lo..hi."""
    return max(max(int(lo), ~int(hi), 0).bit_length(), max(int(hi), ~int(lo), 0).bit_length()) + 1


class _Pipe:
    """Helpers to write pipeline registers (reset-less: a register's contents only matter when the
    valid bit that travels alongside it is set)."""

    def __init__(self, m: Module, dsp: str = "sim"):
        self.m, self.dsp = m, dsp

    def reg(self, value, shape=None, name=None):
        """A register of `shape` (default: the value's shape) loaded with `value` every cycle."""
        sig = Signal(shape if shape is not None else value.shape(), name=name, reset_less=True)
        self.m.d.sync += sig.eq(value)
        return sig

    def delay(self, value, cycles: int, name=None):
        for j in range(cycles):
            value = self.reg(value, name=None if name is None else f"{name}_d{j}")
        return value

    def table(self, tables, name, layout, init, addr):
        """ROM `name` (`layout`, words `init`) read at `addr`: its word two cycles later, in a register.
        A port of a shared ROM (`tables.read`, if it shares this one), or its own Memory and a register."""
        if tables is not None:
            words = [Const.cast(layout.const(v) if isinstance(v, dict) else Const(v, layout)).value for v in init]
            width = layout.size if isinstance(layout, data.Layout) else layout.width
            shared = tables.read(self.m, name, width, words, addr)
            if shared is not None:
                return shared
        rom = Memory(shape=layout, depth=len(init), init=init)
        self.m.submodules[name] = rom
        rp = rom.read_port(domain="sync")
        self.m.d.comb += rp.addr.eq(addr)
        return self.reg(Value.cast(rp.data), name=f"{name}_q")

    def product(self, a, b, latency: int, name=None):
        """The exact product a * b after `latency` cycles (>= its `product_latency`): DSP-sized partial
        products and their sum (hw/rtl_fixed.py `pipelined_product`), or for a constant b (an int) shifts
        and adds when they take few adders (`constant_product`), then delay registers, so that the
        latency does not depend on the operands' widths or on the form built."""
        built = constant_product(self.m, a, b, name) if isinstance(b, int) else None
        prod, lat = built or registered_product(self.m, a, b, name, self.dsp)
        if lat > latency:
            raise AssertionError(f"product {name} takes {lat} cycles, more than the {latency} scheduled")
        return self.delay(prod, latency - lat)


def _delay_valid(m, i_valid, o_valid, latency):
    """o_valid is i_valid delayed by `latency` registers (the units never stall)."""
    valid = i_valid
    for j in range(latency):
        v = Signal(name=f"valid_{j + 1}")
        m.d.sync += v.eq(valid)
        valid = v
    m.d.comb += o_valid.eq(valid)


class RsqrtUnit(wiring.Component):
    """Reciprocal square root 1/sqrt(v), bit-true to a `hw.funcunits.Rsqrt` model (the specification).

    Parameters
    ----------
    model : :class:`hw.funcunits.Rsqrt`
        The NumPy model; its formats, ROM contents (`seed_table`), mantissa width `M`, iterate width `Y`,
        `seed_bits` and `newton_steps` define the unit.
    tables : where its ROMs come from (None: its own; hw/stream/tables.py).
    dsp : its multipliers' variant (hw/rtl_fixed.py DSP_VARIANTS), "sim" or "ecp5".

    Attributes
    ----------
    i : ``In(stream.Signature(raw input shape, always_ready=True))``
        Raw input x of `model.in_shape` (signed or unsigned like the format).
    o : ``Out(stream.Signature(StructLayout({"value": raw output, "saturated": 1}), always_ready=True))``
        `value` is the model's output for x; `saturated` is 1 exactly when the model counts one
        saturation for this element (x <= 0, or a result above the output format's maximum).
    latency : int
        ``7 + 15 * model.newton_steps`` cycles from an accepted input to its output: 3 cycles of
        normalisation, 1 of seed ROM, 1 of ROM output register, 15 per Newton step (3 products of
        PRODUCT_LATENCY = 4 cycles, 3 roundings of 1), 2 of denormalisation.

    Algorithm (the model's steps 1-5; N = newton_steps; each cycle below ends in a register, and an
    input accepted in cycle 0 is in the register of cycle j after j clock edges):

    - cycle 1: x > 0 flag; bit length n of x and the shift Wn - n (priority encoder; x <= 0 is treated
      as x = 1);
    - cycle 2: xn = x << (Wn - n) (the leading one at bit Wn - 1, Wn = bit length of the largest input);
      a table indexed by n gives d = (n - fi) mod 2 (so k = n + d), and the output shift
      s = Y + (k - fi) / 2 - fo as a right shift rs = clamp(s, 0, Y + 3) and a left shift
      ls = clamp(-s, 0, out.width) (every y >= 1 shifted left by out.width overflows, as in the model);
    - cycle 3: m = x 2^(M - k) = xn 2^(M - Wn - d): an exact left shift, or a rounding right shift
      (xn + 2^(r-1)) >> r, r = Wn + d - M, clamped to 2^M - 1 (the model's shift_round of x: xn's
      low Wn - n bits are zero);
    - cycle 4: seed ROM (3 * 2^(seed_bits-2) words of Y + 2 bits, `seed_table`, synchronous read) at
      address (m >> (M - seed_bits)) - 2^(seed_bits-2);
    - cycle 5: y = y0, the ROM word registered (a block RAM's clock-to-output delay leaves no room for a
      multiplier in the same cycle);
    - N Newton steps of 9 cycles each: product y*y (2 cycles); y2 = (y*y + 2^(Y-1)) >> Y; product m*y2
      (2 cycles); t = 3 2^Y - ((m*y2 + 2^(M-1)) >> M), formed in one subtraction as
      (3 2^(Y+M) + 2^(M-1) - 1 - m*y2) >> M (an identity of floors); product y*t (2 cycles);
      y = (y*t + 2^Y) >> (Y + 1). Each product is exact (hw/rtl_fixed.py `pipelined_product`): operands
      wider than one 18x18 multiplier are split into limbs (18 bits from the LSB, all unsigned) whose
      partial products (a multiplier each, or rows in logic for a limb of at most 4 bits) are registered
      in the first cycle and summed in the second; a product that fits one multiplier is registered in
      the first cycle and delayed in the second;
    - cycle 6 + 9N: the right-shift candidate (2y) >> rs, the left-shift candidate y << ls and whether
      it exceeds max_raw;
    - cycle 7 + 9N: ((2y >> rs) + 1) >> 1 (= (y + 2^(rs-1)) >> rs for rs >= 1, y for rs = 0); select the
      left- or right-shift result; saturate into out_shape: x <= 0 or a result above max_raw gives
      max_raw with `saturated` = 1.

    Throughput: one input per cycle, no stalls. Widths: y is UQ(2, Y), y2 and h are UQ(3, Y), t is
    UQ(2, Y) as in the model (they hold because the seed's relative error is below 1/8, checked at
    construction). Products: (Y+2) x (Y+2), M x (Y+3), (Y+2) x (Y+2) bits per Newton step: 22 x 22,
    20 x 23, 22 x 22 for an 18-bit output with 2 guard bits (1, 2 and 1 multipliers; the partial products
    of 4-bit and narrower top limbs are rows in logic), 36 x 36, 34 x 37, 36 x 36 for a 32-bit output
    (4 multipliers each).
    """

    def __init__(self, model: Rsqrt, tables=None, dsp: str = "sim"):
        if not isinstance(model, Rsqrt):
            raise TypeError(f"RsqrtUnit needs a hw.funcunits.Rsqrt model, got {type(model).__name__} "
                            f"({model!r})")
        self.model, self.tables, self.dsp = model, tables, dsp
        if model.seed_relative_error() >= 0.125:
            raise ValueError(f"RsqrtUnit: seed error {model.seed_relative_error():g} too large for the "
                             f"fixed internal formats")
        self.latency = 7 + (3 + 3 * PRODUCT_LATENCY) * model.newton_steps
        # its memories, known at construction (name, depth, width): the seed ROM
        self.memories = [{"name": "seed_rom", "depth": len(model.seed_table), "width": model.Y + 2}]
        out = model.out_shape
        super().__init__({
            "i": In(stream.Signature(_raw_shape(model.in_shape), always_ready=True)),
            "o": Out(stream.Signature(data.StructLayout({"value": _raw_shape(out), "saturated": 1}),
                                      always_ready=True)),
        })

    def elaborate(self, platform):
        m = Module()
        p = _Pipe(m, self.dsp)
        md = self.model
        M, Y, sb = md.M, md.Y, md.seed_bits

        _delay_valid(m, self.i.valid, self.o.valid, self.latency)   # o.valid = i.valid, latency later

        # ---- cycles 1 to 3: normalise
        m3, rs3, ls3, pos3 = _rsqrt_normalise(m, p, self.i.payload, md)

        # ---- cycle 4: seed ROM
        # ---- cycle 5: the ROM word in a register (block RAM clock-to-output is slow: no arithmetic after it)
        y = p.table(self.tables, "seed_rom", unsigned(Y + 2), [int(v) for v in md.seed_table],
                    m3[M - sb:] - md.idx_lo)
        mm, rs_, ls_, pos_ = [p.delay(s_, 2) for s_ in (m3, rs3, ls3, pos3)]

        # ---- Newton steps, 3 + 3 PRODUCT_LATENCY cycles each
        T_CONST = (3 << (Y + M)) + (1 << (M - 1)) - 1
        for step in range(md.newton_steps):
            side = [mm, rs_, ls_, pos_]
            pyy = p.product(y, y, PRODUCT_LATENCY, name=f"n{step}_yy")
            y2 = p.reg((pyy + (1 << (Y - 1))).shift_right(Y), unsigned(Y + 3), name=f"n{step}_y2")
            y_ = p.delay(y, PRODUCT_LATENCY + 1)
            side = [p.delay(s_, PRODUCT_LATENCY + 1) for s_ in side]
            pmh = p.product(side[0], y2, PRODUCT_LATENCY, name=f"n{step}_my2")
            # t = 3 2^Y - floor((p + 2^(M-1)) / 2^M) = floor((3 2^(Y+M) + 2^(M-1) - 1 - p) / 2^M)
            t = p.reg((Const(T_CONST, unsigned(_bits(T_CONST))) - pmh).shift_right(M), unsigned(Y + 2),
                      name=f"n{step}_t")
            y_ = p.delay(y_, PRODUCT_LATENCY + 1)
            side = [p.delay(s_, PRODUCT_LATENCY + 1) for s_ in side]
            pyt = p.product(y_, t, PRODUCT_LATENCY, name=f"n{step}_yt")
            y = p.reg((pyt + (1 << Y)).shift_right(Y + 1), unsigned(Y + 2), name=f"n{step}_y")
            mm, rs_, ls_, pos_ = [p.delay(s_, PRODUCT_LATENCY + 1) for s_ in side]

        # ---- denormalise and saturate (2 cycles)
        value, satr = _rsqrt_denormalise(p, y, rs_, ls_, pos_, md)
        m.d.comb += [self.o.payload.value.eq(value), self.o.payload.saturated.eq(satr)]
        return m


def _rsqrt_normalise(m, p: _Pipe, x, md):
    """Cycles 1 to 3 of RsqrtUnit and RsqrtTableUnit (the models' step 2): the registered mantissa m3 in
    UQ(0, M) (M = md.M), the output's right and left shifts and the x > 0 flag, 3 cycles after x."""
    ins, out = md.in_shape, md.out_shape
    M, Y, fi, fo = md.M, md.Y, ins.f, out.f
    Wn = _bits(ins.max_raw)          # bit length of the largest positive input
    L_CAP = out.width                # a left shift by >= out.width overflows for every y >= 1

    # ---- cycle 1: sign test and bit length
    positive = (x > 0)
    xs = Signal(Wn)
    m.d.comb += xs.eq(Mux(positive, x[:Wn], 1))
    # the highest set bit b, one-hot (each bit tested against the OR of the bits above it), encoded as
    # n = b + 1 and the shift Wn - n, so that the shift in cycle 2 starts from a register: a chain of Wn
    # priority multiplexers was a 10 to 11 ns path on the 1e4 square
    top = [xs[b] & ~xs[b + 1:].any() if b + 1 < Wn else xs[b] for b in range(Wn)]
    n = Cat(*[Cat(*[top[b] for b in range(Wn) if (b + 1) >> k & 1]).any() for k in range(_bits(Wn))])
    lsh = Cat(*[Cat(*[top[b] for b in range(Wn) if (Wn - 1 - b) >> k & 1] or [Const(0, 1)]).any()
                for k in range(max(1, _bits(Wn - 1)))])
    pos1, xs1, n1 = p.reg(positive, name="pos1"), p.reg(xs, name="xs1"), p.reg(n, name="n1")
    lsh1 = p.reg(lsh, name="lsh1")

    # ---- cycle 2: left-normalise; per-n constants (d, output shifts)
    d = Signal()
    rs = Signal(range(Y + 4))
    ls = Signal(range(L_CAP + 1))
    with m.Switch(n1):
        for nv in range(1, Wn + 1):
            dv = (nv - fi) & 1
            e = (nv + dv - fi) >> 1
            s = Y + e - fo
            with m.Case(nv):
                m.d.comb += [d.eq(dv), rs.eq(min(max(s, 0), Y + 3)), ls.eq(min(max(-s, 0), L_CAP))]
        with m.Default():           # n = 0 never occurs (xs >= 1)
            m.d.comb += [d.eq(0), rs.eq(0), ls.eq(0)]
    # nextpnr on the 1e4 square: the shift decoded from n1 in this cycle arrived at 10.4 ns
    xn2 = p.reg((xs1 << lsh1)[:Wn], unsigned(Wn), name="xn2")
    d2, rs2, ls2, pos2 = p.reg(d, name="d2"), p.reg(rs, name="rs2"), p.reg(ls, name="ls2"), p.reg(pos1)

    # ---- cycle 3: mantissa m in UQ(0, M)
    def mantissa(dv):
        r = Wn + dv - M
        if r <= 0:
            return xn2.shift_left(-r)                        # exact
        v = (xn2 + (1 << (r - 1))).shift_right(r)            # shift_round
        return Mux(v > (1 << M) - 1, (1 << M) - 1, v)
    m3 = p.reg(Mux(d2, mantissa(1), mantissa(0)), unsigned(M), name="m3")
    return m3, p.reg(rs2), p.reg(ls2), p.reg(pos2)


def _rsqrt_denormalise(p: _Pipe, y, rs_, ls_, pos_, md):
    """The last 2 cycles of RsqrtUnit and RsqrtTableUnit (the models' step 5): y in UQ(2, Y) shifted by
    rs_ / ls_ and saturated into md.out_shape; returns the registered (value, saturated)."""
    out, Y = md.out_shape, md.Y
    rr = p.reg((y.shift_left(1) >> rs_), unsigned(Y + 3), name="dn_r")
    wide = y << ls_
    lv = p.reg(wide[:out.width], unsigned(out.width), name="dn_l")
    lovf = p.reg(wide > out.max_raw, name="dn_lovf")
    useleft = p.reg(ls_ != 0, name="dn_useleft")
    posf = p.reg(pos_, name="dn_pos")
    res_r = (rr + 1).shift_right(1)
    # res_r > max  <=>  rr + 1 >= 2 max + 2  <=>  rr > 2 max: compared on rr beside the rounding adder, not
    # after it (nextpnr: the two carry chains in series were the critical path at 111.7 MHz)
    ovf = Mux(useleft, lovf, rr > 2 * out.max_raw)
    res = Mux(useleft, lv, res_r)
    sat = ~posf | ovf
    value = p.reg(Mux(sat, out.max_raw, res), _raw_shape(out), name="out_value")
    satr = p.reg(sat, name="out_sat")
    return value, satr


class RsqrtTableUnit(wiring.Component):
    """Reciprocal square root 1/sqrt(v) by table and linear interpolation, bit-true to a
    `hw.funcunits.RsqrtTable` model (the specification): one product and one ROM.

    Parameters
    ----------
    model : :class:`hw.funcunits.RsqrtTable`
        The NumPy model; its formats, tables (`c0`, `slope`), mantissa width `M`, iterate width `Y`, `S`
        and `F` define the unit.
    tables, dsp : as :class:`RsqrtUnit`.

    Attributes
    ----------
    i, o : as :class:`RsqrtUnit` (raw input; output ``value`` and ``saturated``).
    latency : int
        ``8 + PRODUCT_LATENCY`` = 12 cycles: 3 of normalisation, 1 of ROM, 1 of ROM output register,
        PRODUCT_LATENCY of the product, 1 of interpolation, 2 of denormalisation.

    Algorithm (the model's steps 1-5; each cycle ends in a register):

    - cycles 1 to 3: the mantissa m in UQ(0, M) and the output shifts, as RsqrtUnit;
    - cycle 4: ROM of 2^S words at address Cat(j, o): o = m[M-1], j = m[M-S:M-1] (o = 1) or
      m[M-S-1:M-2] (o = 0); word = (c0 - 2^Y in Y bits, sl); frac = m[:F] (o = 1) or m[:F-1] << 1 (o = 0);
    - cycle 5: the ROM word in a register (no arithmetic after a block RAM's output);
    - cycles 6 to 9: the product frac * sl (hw/rtl_fixed.py `pipelined_product`: F x bits(sl) bits,
      12 x 13 for an 18-bit output with the default 4 guard bits: one multiplier);
    - cycle 10: y = c0 - ((frac sl + 2^(F-1)) >> F), formed in one subtraction as
      (c0 2^F + 2^(F-1) - 1 - frac sl) >> F (an identity of floors), the constant part a concatenation
      (1, the ROM's c0 - 2^Y, then 2^(F-1) - 1 in F bits);
    - cycles 11 and 12: denormalise and saturate, as RsqrtUnit.

    Throughput: one input per cycle, no stalls.
    """

    def __init__(self, model: RsqrtTable, tables=None, dsp: str = "sim"):
        if not isinstance(model, RsqrtTable):
            raise TypeError(f"RsqrtTableUnit needs a hw.funcunits.RsqrtTable model, got {type(model).__name__} "
                            f"({model!r})")
        self.model, self.tables, self.dsp = model, tables, dsp
        self.latency = 8 + PRODUCT_LATENCY
        # its memories, known at construction (name, depth, width): the table ROM
        layout, init = self._rom_layout()
        self.memories = [{"name": "table_rom", "depth": len(init), "width": layout.size}]
        super().__init__({
            "i": In(stream.Signature(_raw_shape(model.in_shape), always_ready=True)),
            "o": Out(stream.Signature(data.StructLayout({"value": _raw_shape(model.out_shape), "saturated": 1}),
                                      always_ready=True)),
        })

    def _rom_layout(self):
        """The table ROM's word layout (c0 - 2^Y in Y bits, the slope) and its 2^S words."""
        md = self.model
        layout = data.StructLayout({"c0": unsigned(md.Y), "sl": unsigned(_bits(int(md.slope.max())))})
        init = [{"c0": int(c) - (1 << md.Y), "sl": int(v)} for c, v in zip(md.c0, md.slope)]
        return layout, init

    def elaborate(self, platform):
        m = Module()
        p = _Pipe(m, self.dsp)
        md = self.model
        M, Y, S, F = md.M, md.Y, md.S, md.F

        _delay_valid(m, self.i.valid, self.o.valid, self.latency)

        # ---- cycles 1 to 3: normalise
        m3, rs3, ls3, pos3 = _rsqrt_normalise(m, p, self.i.payload, md)

        # ---- cycle 4: table ROM
        layout, init = self._rom_layout()
        o = m3[M - 1]
        j = Mux(o, m3[M - S:M - 1], m3[M - S - 1:M - 2])
        frac = Mux(o, m3[:F], Cat(Const(0, 1), m3[:F - 1]))
        # ---- cycle 5: the ROM word in a register
        row = data.View(layout, p.table(self.tables, "table_rom", layout, init, Cat(j, o)))
        frac5 = p.delay(frac, 2, name="frac")
        rs_, ls_, pos_ = [p.delay(s_, 2) for s_ in (rs3, ls3, pos3)]

        # ---- cycles 6 and 7: the product; cycle 8: y = c0 - ((frac sl + 2^(F-1)) >> F)
        #      = floor((c0 2^F + 2^(F-1) - 1 - frac sl) / 2^F)
        prod = p.product(frac5, row.sl, PRODUCT_LATENCY, name="frac_sl")
        c0f = p.delay(Cat(Const((1 << (F - 1)) - 1, F), row.c0, Const(1, 1)), PRODUCT_LATENCY, name="c0f")
        y = p.reg((c0f - prod).shift_right(F)[:Y + 2], unsigned(Y + 2), name="y")
        rs_, ls_, pos_ = [p.delay(s_, PRODUCT_LATENCY + 1) for s_ in (rs_, ls_, pos_)]

        # ---- cycles 9 and 10: denormalise and saturate
        value, satr = _rsqrt_denormalise(p, y, rs_, ls_, pos_, md)
        m.d.comb += [self.o.payload.value.eq(value), self.o.payload.saturated.eq(satr)]
        return m


class InverseTableUnit(wiring.Component):
    """An inverse table (the inverse of an odd curve and its companions), bit-true to a
    `hw.funcunits.InverseTable` model.

    Parameters
    ----------
    model : :class:`hw.funcunits.InverseTable`
        The NumPy model (the specification): thresholds `Y1`, `Y2`, scale `K_raw`, offset `OFF`,
        `pos_shift`, `S`, `P`, the tables `tabs` with their clip flags `clips`, one per output format in
        `out_shapes`.
    tables, dsp : as :class:`RsqrtUnit`.

    Attributes
    ----------
    i : ``In(stream.Signature(raw in_shape, always_ready=True))``
        Raw magnitude y (>= 0; the model rejects negative inputs, so no output is specified for them).
    o : ``Out(stream.Signature(StructLayout({"out0": ..., "out1": ..., "below": 1, "above": 1,
        "saturations": unsigned(n)}), always_ready=True))``
        ``out<k>`` is the model's output k (raw, in ``model.out_shapes[k]``; the quantity
        ``model.curve.outputs[k]``: out0 the inverse, out1... the companions in order; `output_fields`
        lists the field names). ``below`` is y <= Y1 and ``above`` is y >= Y2 (the model's comparisons,
        as `hw.arith.FixedArith.inverse` reports them: the linear pieces the datapath applies instead of
        the table). ``saturations`` is the number of saturations the model counts for this item (one per
        output whose interpolation uses a clipped table entry), `n` = bits of the number of outputs.
    latency : int
        12 cycles from an accepted input to its output (4 + 2 products of PRODUCT_LATENCY = 4 cycles).

    Algorithm (the model's steps 1-4; every stage ends in a register; products are exact,
    hw/rtl_fixed.py `pipelined_product`: operands wider than one 18x18 multiplier are split into limbs
    whose partial products are registered in the first cycle and summed in the second, a product that fits
    one multiplier is registered in the first cycle and delayed in the second):

    - cycles 1 to 4: product y * K_raw; comparisons y <= Y1 (below), y >= Y2 (above) in cycle 1, then
      delayed (to cycle 5 for the position, to the output for the `below` and `above` fields);
    - cycle 5: position pos in UQ(S, P): for pos_shift s > 0, q = y K_raw - OFF + 2^(s-1) in one
      subtraction and pos = clamp(q >> s, 0, 2^(S+P)); for s <= 0, pos = min(D << -s, 2^(S+P)) with
      D = max(y K_raw - OFF, 0); then 0 for y <= Y1, 2^(S+P) for y >= Y2; registered as idx = pos >> P,
      frac = pos mod 2^P (idx = 2^S - 1, frac = 2^P at the end point 2^(S+P));
    - cycle 6: one ROM per output of 2^S words, read synchronously at idx. Word j holds tab[j], the
      difference tab[j+1] - tab[j] and the clip flags of entries j and j+1;
    - cycle 7: the ROM words registered (a block RAM's clock-to-output delay leaves no room for a
      multiplier in the same cycle);
    - cycles 8 to 11: products frac * (tab[idx+1] - tab[idx]); saturation flags
      clip[idx] | (clip[idx+1] & frac != 0) (in cycle 8, then delayed);
    - cycle 12: out = tab[idx] + ((product + 2^(P-1)) >> P) for every table (it lies between two entries:
      it always fits), and the sum of the saturation flags; the output registers.

    Throughput: one input per cycle, no stalls.
    """

    def __init__(self, model: InverseTable, tables=None, dsp: str = "sim"):
        if not isinstance(model, InverseTable):
            raise TypeError(f"InverseTableUnit needs a hw.funcunits.InverseTable model, got "
                            f"{type(model).__name__} ({model!r})")
        self.model, self.tables, self.dsp = model, tables, dsp
        self.latency = 4 + 2 * PRODUCT_LATENCY
        n = len(model.out_shapes)
        self.output_fields = tuple(f"out{k}" for k in range(n))
        fields = {f: _raw_shape(s) for f, s in zip(self.output_fields, model.out_shapes)}
        fields.update({"below": 1, "above": 1, "saturations": unsigned(_bits(n))})
        # its memories, known at construction (name, depth, width): one table ROM per output
        self.memories = []
        for k, (tab, clip, shape) in enumerate(zip(model.tabs, model.clips, model.out_shapes)):
            layout, init = self._rom_layout(tab, clip, shape)
            self.memories.append({"name": f"rom_{k}", "depth": len(init), "width": layout.size})
        super().__init__({
            "i": In(stream.Signature(_raw_shape(model.in_shape), always_ready=True)),
            "o": Out(stream.Signature(data.StructLayout(fields), always_ready=True)),
        })

    @staticmethod
    def _rom_layout(tab, clip, shape: Shape):
        tab = [int(v) for v in tab]
        deltas = [b - a for a, b in zip(tab[:-1], tab[1:])]
        layout = data.StructLayout({"lo": _raw_shape(shape),
                                    "delta": signed(_signed_bits(min(deltas), max(deltas))),
                                    "clip_lo": 1, "clip_hi": 1})
        init = [{"lo": tab[j], "delta": deltas[j], "clip_lo": int(bool(clip[j])),
                 "clip_hi": int(bool(clip[j + 1]))} for j in range(len(deltas))]
        return layout, init

    def elaborate(self, platform):
        m = Module()
        p = _Pipe(m, self.dsp)
        md = self.model
        ys = md.in_shape
        S, P = md.S, md.P
        cap = 1 << (S + P)
        L = self.latency

        _delay_valid(m, self.i.valid, self.o.valid, L)

        # ---- cycles 1 and 2: product and the pieces
        y = self.i.payload
        prod = p.product(y, md.K_raw, PRODUCT_LATENCY, name="yk")
        # the product as a signed value (zero-extended when y is unsigned), for the signed subtraction
        prod_s = prod if prod.shape().signed else Cat(prod, Const(0, 1)).as_signed()
        below1 = p.reg(y <= md.Y1, unsigned(1), name="below")
        above1 = p.reg(y >= md.Y2 if md.Y2 <= ys.max_raw else Const(0), unsigned(1), name="above")
        low = p.delay(below1, PRODUCT_LATENCY - 1)
        high = p.delay(above1, PRODUCT_LATENCY - 1)

        # ---- cycle 3: position pos, registered as the table index idx = pos >> P and frac = pos mod 2^P
        # (idx = 2^S - 1, frac = 2^P at the end point pos = 2^(S+P)): the shared tables' address then
        # leaves a register (nextpnr on the 1e4 square: idx formed from pos in cycle 4 on its way to a
        # lane pair's shared Psi table arrived at 10.3 ns)
        s = md.pos_shift
        inner = Signal(range(cap))                      # pos below the end point
        end_i = Signal()                                # pos at the end point
        if s > 0:
            d_max = max(ys.max_raw * md.K_raw - md.OFF, 0)
            s_eff = min(s, d_max.bit_length() + 1)      # shift_round(D, s) = 0 for all D < 2^(s_eff-1)
            q = Signal(signed(max(len(prod_s), _bits(abs(md.OFF))) + 3))
            m.d.comb += q.eq(prod_s - (md.OFF - (1 << (s_eff - 1))))
            qs = q.shift_right(s_eff)
            with m.If(q < 0):                           # D < 0: pos = 0
                m.d.comb += inner.eq(0)
            with m.Elif(qs >= cap):
                m.d.comb += end_i.eq(1)
            with m.Else():
                m.d.comb += inner.eq(qs)
        else:
            lim = 1 << max(S + P + s, 0)
            dd = Signal(signed(max(len(prod_s), _bits(abs(md.OFF))) + 2))
            m.d.comb += dd.eq(prod_s - md.OFF)
            with m.If(dd < 0):
                m.d.comb += inner.eq(0)
            with m.Elif(dd >= lim):
                m.d.comb += end_i.eq(1)
            with m.Else():
                m.d.comb += inner.eq(dd[:max(S + P + s, 0)].as_unsigned().shift_left(-s))
        end = ~low & (high | end_i)                     # pos = 0 for y <= Y1, 2^(S+P) for y >= Y2
        idx = p.reg(Mux(low, 0, Mux(end, (1 << S) - 1, inner[P:S + P])), unsigned(S), name="idx")
        frac = p.reg(Mux(low, 0, Mux(end, 1 << P, inner[:P])), unsigned(P + 1), name="frac")

        # ---- cycle 4: table ROMs at idx
        frac5 = p.delay(frac, 2, name="frac")
        rows = []
        for k, (tab, clip, shape) in enumerate(zip(md.tabs, md.clips, md.out_shapes)):
            layout, init = self._rom_layout(tab, clip, shape)
            # ---- cycle 5: the ROM word in a register (no arithmetic after a block RAM's output)
            rows.append(data.View(layout, p.table(self.tables, f"rom_{k}", layout, init, idx)))

        # ---- cycles 6 to 8: interpolation, saturation count, the output registers
        sats = []
        for k, (row, shape, field) in enumerate(zip(rows, md.out_shapes, self.output_fields)):
            pr = p.product(frac5, row.delta, PRODUCT_LATENCY, name=f"prod_{k}")
            lo = p.delay(row.lo, PRODUCT_LATENCY, name=f"lo_{k}")
            sats.append(p.delay(p.reg(row.clip_lo | (row.clip_hi & (frac5 != 0)), name=f"sat_{k}"),
                                PRODUCT_LATENCY - 1))
            val = p.reg(lo + (pr + (1 << (P - 1))).shift_right(P), _raw_shape(shape), name=f"out_{k}")
            m.d.comb += getattr(self.o.payload, field).eq(val)
        nsat = sats[0]
        for f_ in sats[1:]:
            nsat = nsat + f_
        o_sat = p.reg(nsat, self.o.payload.saturations.shape(), name="out_sat")
        o_below = p.delay(below1, L - 1, name="out_below")
        o_above = p.delay(above1, L - 1, name="out_above")
        m.d.comb += [self.o.payload.saturations.eq(o_sat), self.o.payload.below.eq(o_below),
                     self.o.payload.above.eq(o_above)]
        return m
