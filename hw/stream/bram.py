"""`BlockRam`: a simple dual-port block RAM (or ROM) with its output register, read latency 2.

One write port and one read port in one clock domain. The address presented in cycle t gives its word in
cycle t + 2 (`LATENCY`), from a register: the block RAM's own output register, so that nothing but
routing follows a block RAM's clock-to-output delay (5.8 ns on an ECP5 without the register, 0.95 ns
with it). A read presented in the cycle of a write to the same word is undefined (callers never use its
data); writes are visible to reads presented from the next cycle on. A word may be written in
`segments` equal parts, each with its own enable (the ECP5's byte enables).

Two variants, chosen at construction (`ram=`):

- "sim": an Amaranth `Memory` with a synchronous, non-transparent read port, plus a register. For
  Amaranth's simulator, Icarus and Verilator.
- "ecp5": `DP16KD` instances (`rheo synth`): Yosys never sets a DP16KD's output register itself
  (`memory_libmap` emits REGMODE NOREG), so the core instantiates them with REGMODE_B = "OUTREG". Each
  block is 512 x 36 (pseudo dual port: DATA_WIDTH_A = DATA_WIDTH_B = 36, REGMODE_A = REGMODE_B =
  "OUTREG"), 1024 x 18 or 2048 x 9, whichever needs the fewest blocks; deeper memories take rows of
  blocks, whose outputs a registered row address selects. Segments are padded to whole 9-bit bytes.
  Pins and INITVAL layout follow Yosys's lattice/brams_map_16kd.v; the Verilog model of the subset used
  is `DP16KD_MODEL` (hw/stream/dp16kd.v), which simulators need beside the core's Verilog.

A ROM may have a second read port (`read_ports=2`, members `r2_addr`, `r2_data`, the same latency):
two readers share one copy, e.g. two lanes' function-unit tables. The "ecp5" variant then runs the
DP16KD in true dual-port mode, both ports reading with their output registers (REGMODE_A = REGMODE_B =
"OUTREG"); that mode has no 36-bit width, so blocks are 1024 x 18 or 2048 x 9.

A writable memory may instead be `distributed` (LUT RAM): an Amaranth `Memory` marked
`ram_style = "distributed"`, which Yosys maps to TRELLIS_DPR16X4 (16 x 4 bits each, asynchronous read):
the read address registered, the asynchronous read and its multiplexer, the output register; the write
registered too, so that a read presented after a write still sees it: the same ports, latency and
read-after-write behaviour in either variant (nextpnr, the 1e4 square at P = 5 with the read address unregistered:
the element lane's slot adder, 27 ns of routing across the die and the LUT RAM's read in one cycle,
27.7 MHz). It costs
no DP16KD; a shallow, wide memory (a window copy, a force ring's node copy: 128 words in blocks 512
deep) spends 3/4 of its blocks' bits on nothing, so the core moves such memories into LUT RAM when the
block RAM would not fit otherwise (hw/stream/core.py, `fit_block_ram`).

A writable memory may register its inputs (`registered=True`, one cycle more: a read's latency 3, a
write lands at the end of the next cycle): in the "ecp5" variant each block registers its own address,
enables and data (kept apart in Yosys), so that no route runs from one register to the blocks of a
memory spread over the die (the 1e4 square: a window copy's read address into one of its six blocks,
13.6 ns of routing); the other variants register them once.

`blocks()` states the DP16KD count of the "ecp5" variant for either variant (the manifest's budget).
"""
from __future__ import annotations

from pathlib import Path

from amaranth.hdl import Cat, ClockSignal, Const, Instance, Module, Mux, Signal, unsigned
from amaranth.lib import wiring
from amaranth.lib.memory import Memory
from amaranth.lib.wiring import In, Out

from ..rtl_fixed import KEEP_APART_TAG    # registers Yosys must not merge (sim/synth.py)
from .nodeword import delay

__all__ = ["BlockRam", "LATENCY", "RAM_VARIANTS", "DP16KD_MODEL", "plan_blocks", "ram_record", "lut_rams"]

LATENCY = 2
RAM_VARIANTS = ("sim", "ecp5")
DP16KD_MODEL = Path(__file__).resolve().parent / "dp16kd.v"
BYTE = 9
MODES = ((36, 512), (18, 1024), (9, 2048))       # DP16KD data width, depth


def addr_bits(depth: int) -> int:
    return max(1, int(depth - 1).bit_length())


def _layout(width: int, segments: int):
    """(padded width, segment width, padded segment width): segments start at multiples of 9 bits."""
    if segments == 1:
        return width, width, width
    seg = width // segments
    pseg = -(-seg // BYTE) * BYTE
    return pseg * segments, seg, pseg


def plan_blocks(width: int, depth: int, segments: int = 1, read_ports: int = 1):
    """(data width of the blocks, depth of a block, rows, columns) with the fewest DP16KD blocks (two
    read ports: true dual-port mode, no 36-bit width)."""
    total, _, _ = _layout(width, segments)
    best = None
    for w, d in MODES[read_ports - 1:]:
        rows, cols = -(-depth // d), -(-total // w)
        cand = (rows * cols, rows, -w, w, d, rows, cols)
        if best is None or cand < best:
            best = cand
    _, _, _, w, d, rows, cols = best
    return w, d, rows, cols


def lut_rams(width: int, depth: int, segments: int = 1) -> int:
    """TRELLIS_DPR16X4 (16 words x 4 bits) of a distributed memory: each segment has its own columns."""
    return segments * -(-(width // segments) // 4) * -(-depth // 16)


def ram_record(name: str, width: int, depth: int, segments: int = 1, read_ports: int = 1,
               distributed: bool = False) -> dict:
    """A memory inventory entry: name, depth, width, the DP16KD blocks of the "ecp5" variant and, for a
    distributed memory (no blocks), its TRELLIS_DPR16X4 count."""
    if distributed:
        return {"name": name, "depth": depth, "width": width, "dp16kd": 0,
                "dpr16x4": lut_rams(width, depth, segments)}
    _, _, rows, cols = plan_blocks(width, depth, segments, read_ports)
    return {"name": name, "depth": depth, "width": width, "dp16kd": rows * cols}


class BlockRam(wiring.Component):
    """A simple dual-port RAM of `depth` words of `width` bits (a ROM with `writable=False`).

    Parameters
    ----------
    width, depth : int
    init : list of int, optional
        Initial contents (a ROM's contents).
    segments : int
        The word is written in this many equal parts, each with its own bit of `w_en`.
    writable : bool
        False: a ROM (no write port; `w_*` are ignored).
    ram : "sim" or "ecp5"
        The variant (module docstring).
    read_ports : 1 or 2
        2: a ROM with a second read port (`r2_addr`, `r2_data`).
    distributed : bool
        LUT RAM instead of block RAM (a writable memory with one read port; module docstring).
    registered : bool
        Register the inputs (every block its own in the "ecp5" variant): read latency LATENCY + 1, writes
        one cycle later (a writable memory with one read port; module docstring).

    Members
    -------
    w_addr, w_data, w_en : In
        Write: word `w_addr` takes `w_data` in the parts whose `w_en` bits are set, at the clock edge.
    r_addr : In
        Read address; `r_data` (Out) holds that word `latency` cycles later (LATENCY = 2, 3 when
        `registered`; `r2_addr`, `r2_data`: the second read port).
    """

    def __init__(self, width: int, depth: int, *, init=None, segments: int = 1, writable: bool = True,
                 ram: str = "sim", read_ports: int = 1, distributed: bool = False, registered: bool = False):
        if ram not in RAM_VARIANTS:
            raise ValueError(f"unknown block RAM variant {ram!r} (known: {', '.join(RAM_VARIANTS)})")
        if width < 1 or depth < 1:
            raise ValueError(f"a block RAM needs width and depth >= 1, got {width} x {depth}")
        if segments < 1 or width % segments:
            raise ValueError(f"width {width} does not split into {segments} segments")
        if read_ports not in (1, 2) or (read_ports == 2 and writable):
            raise ValueError(f"{read_ports} read ports: a BlockRam has 1, a ROM 1 or 2 (its port A reads then)")
        if distributed and (not writable or read_ports != 1):
            raise ValueError("a distributed (LUT RAM) BlockRam is a writable memory with one read port")
        if registered and (not writable or read_ports != 1):
            raise ValueError("a BlockRam with registered inputs is a writable memory with one read port")
        self.width, self.depth, self.segments, self.writable, self.ram = width, depth, segments, writable, ram
        self.read_ports, self.distributed, self.registered = read_ports, distributed, registered
        self.latency = LATENCY + int(registered)
        self.init = [int(v) & ((1 << width) - 1) for v in (init or [])]
        if len(self.init) > depth:
            raise ValueError(f"{len(self.init)} initial words for a depth of {depth}")
        self.abits = addr_bits(depth)
        members = {"w_addr": In(self.abits), "w_data": In(width), "w_en": In(segments),
                   "r_addr": In(self.abits), "r_data": Out(width)}
        if read_ports == 2:
            members.update({"r2_addr": In(self.abits), "r2_data": Out(width)})
        super().__init__(members)

    def _reads(self):
        """(address, data) of each read port."""
        return [(self.r_addr, self.r_data)] + ([(self.r2_addr, self.r2_data)] if self.read_ports == 2 else [])

    def blocks(self) -> int:
        """DP16KD blocks of the "ecp5" variant."""
        if self.distributed:
            return 0
        _, _, rows, cols = plan_blocks(self.width, self.depth, self.segments, self.read_ports)
        return rows * cols

    def elaborate(self, platform):
        return self._sim() if self.ram == "sim" or self.distributed else self._ecp5()

    # ---- Amaranth Memory and an output register (LUT RAM when distributed)
    def _sim(self):
        m = Module()
        attrs = {"ram_style": "distributed"} if self.distributed else None
        mem = Memory(shape=unsigned(self.width), depth=self.depth, init=self.init, attrs=attrs)
        m.submodules.mem = mem
        w_addr, w_data, w_en, r_addr = (delay(m, v, int(self.registered), f"in_{n}", data=n != "w_en") for v, n in
                                        ((self.w_addr, "w_addr"), (self.w_data, "w_data"), (self.w_en, "w_en"),
                                         (self.r_addr, "r_addr")))
        if self.writable:
            seg = self.width // self.segments
            wp = mem.write_port(granularity=seg if self.segments > 1 else None)
            if self.distributed:
                # the write registered in each copy, as the read address is: a read presented the cycle after
                # a write still sees it (both land a cycle later). Named to be kept apart in Yosys
                # (sim/synth.py), which would otherwise share one write-enable decoder among copies all
                # over the die (nextpnr, the 1e4 square at P = 5: 20.9 ns of routing, 41.3 MHz).
                w_addr, w_data, w_en = (delay(m, v, 1, f"{n}{KEEP_APART_TAG}", data=n != "w_en") for v, n in
                                        ((w_addr, "w_addr"), (w_data, "w_data"), (w_en, "w_en")))
            m.d.comb += [wp.addr.eq(w_addr), wp.data.eq(w_data),
                         wp.en.eq(w_en if self.segments > 1 else w_en[0])]
        reads = [(r_addr, self.r_data)] + self._reads()[1:]
        for addr, data in reads:
            if self.distributed:         # the address registered, then the LUT RAM's asynchronous read
                addr_q = Signal.like(addr, name="r_addr_q", reset_less=True)
                m.d.sync += addr_q.eq(addr)
                rp = mem.read_port(domain="comb")
                m.d.comb += rp.addr.eq(addr_q)
            else:
                rp = mem.read_port(domain="sync")
                m.d.comb += rp.addr.eq(addr)
            m.d.comb += data.eq(delay(m, rp.data, 1, "r_word", data=True))
        return m

    # ---- DP16KD instances
    def _ecp5(self):
        m = Module()
        w, d, rows, cols = plan_blocks(self.width, self.depth, self.segments, self.read_ports)
        total, seg, pseg = _layout(self.width, self.segments)
        lbits = addr_bits(d)
        shift = {36: 5, 18: 4, 9: 3}[w]

        def padded(value):
            """The word in the padded layout (segments at multiples of 9 bits)."""
            if self.segments == 1:
                return value
            return Cat(*[Cat(value[s * seg:(s + 1) * seg], Const(0, pseg - seg)) for s in range(self.segments)])

        wdata = padded(self.w_data)
        nbytes = -(-total // BYTE)
        reads = self._reads()
        outs = [[] for _ in reads]          # per read port, per row: the row's blocks' words
        for r in range(rows):
            dout = [[] for _ in reads]
            for c in range(cols):
                lo = c * w
                # the inputs, each block's own registers when `registered` (kept apart in Yosys): the address,
                # the enables and this block's slice of the data
                w_addr, w_en, r_addr, di = (
                    delay(m, v, int(self.registered), f"{n}_r{r}_c{c}{KEEP_APART_TAG}", data=n != "w_en")
                    for v, n in ((self.w_addr, "w_addr"), (self.w_en, "w_en"), (self.r_addr[:lbits], "r_addr"),
                                 (Cat(wdata[lo:min(lo + w, total)], Const(0, max(0, lo + w - total))), "di")))
                if self.segments > 1:
                    byte_en = [w_en[(b * BYTE) // pseg] for b in range(nbytes)]
                else:
                    byte_en = [w_en[0]] * nbytes
                wsel = (w_addr[lbits:] == r) if rows > 1 else Const(1, 1)
                bits = [Signal(w, name=f"do{p}_r{r}_c{c}") for p in range(len(reads))]
                be = [(byte_en[(lo + k * BYTE) // BYTE] if lo + k * BYTE < total else Const(0, 1)) & wsel
                      & Const(int(self.writable), 1) for k in range(w // BYTE)]
                read_a = (reads[1][0][:lbits], bits[1]) if len(reads) == 2 else None
                m.submodules[f"bram_r{r}_c{c}"] = self._instance(
                    w, shift, lbits, di, bits[0], be, w_addr[:lbits], r_addr,
                    self._initvals(r * d, d, w, lo, total), read_a)
                for p in range(len(reads)):
                    dout[p].append(bits[p])
            for p in range(len(reads)):
                outs[p].append(dout[p])
        for p, (addr, data) in enumerate(reads):
            if rows > 1:
                # the row's blocks selected column by column, each column by a row register of its own
                # (kept apart in Yosys): one register for the whole word sat among blocks all over the die
                # (the 1e4 square's shared Psi table: 13.6 ns of routing to a column's multiplexer)
                row_r = delay(m, addr[lbits:], int(self.registered), f"row{p}_in", data=True)
                rsel = Signal.like(row_r, name=f"row{p}_d1", reset_less=True)
                m.d.sync += rsel.eq(row_r)
                columns = []
                for c in range(cols):
                    rsel2 = Signal.like(row_r, name=f"row{p}_c{c}_d2{KEEP_APART_TAG}", reset_less=True)
                    m.d.sync += rsel2.eq(rsel)
                    col = Signal(w, name=f"word{p}_c{c}")
                    with m.Switch(rsel2):
                        for r in range(rows):
                            with m.Case(r):
                                m.d.comb += col.eq(outs[p][r][c])
                    columns.append(col)
                word = Cat(*columns)[:total]
            else:
                word = Cat(*outs[p][0])[:total]
            if self.segments > 1:
                m.d.comb += data.eq(Cat(*[word[s * pseg:s * pseg + seg] for s in range(self.segments)]))
            else:
                m.d.comb += data.eq(word[:self.width])
        return m

    def _initvals(self, base, d, w, lo, total):
        """INITVAL_00 .. 3F of the block holding words base .. base + d - 1, bits lo .. lo + w - 1."""
        if not self.init:
            return None
        seg, pseg = self.width // self.segments, _layout(self.width, self.segments)[2]
        chunks = [0] * 1024
        for a in range(d):
            if base + a >= len(self.init):
                break
            v = self.init[base + a]
            if self.segments > 1:
                v = sum(((v >> (s * seg)) & ((1 << seg) - 1)) << (s * pseg) for s in range(self.segments))
            bits = (v >> lo) & ((1 << w) - 1)
            if w == 36:
                chunks[2 * a] |= bits & 0x3FFFF
                chunks[2 * a + 1] |= bits >> 18
            elif w == 18:
                chunks[a] |= bits
            else:
                chunks[a >> 1] |= bits << (9 * (a & 1))
        vals = []
        for i in range(64):
            vals.append(sum(chunks[i * 16 + k] << (20 * k) for k in range(16)))
        return vals

    def _instance(self, w, shift, lbits, di, do, be, waddr, raddr, initvals, read_a=None):
        """One DP16KD: port A writes, port B reads (REGMODE_B = "OUTREG"); with `read_a` = (address,
        data), port A reads too (a ROM's second port, w <= 18, REGMODE_A = "OUTREG")."""
        zero = Const(0, 1)
        ada = [zero] * 14
        adb = [zero] * 14
        for k in range(min(lbits, len(waddr))):
            ada[shift + k] = waddr[k] if read_a is None else read_a[0][k]
            adb[shift + k] = raddr[k]
        any_en = Cat(*be).any()
        if w == 36:
            for k in range(4):
                ada[k] = be[k]
            wea, cea = Const(1, 1), any_en
        elif w == 18:
            ada[0], ada[1] = be[0], be[1]
            wea, cea = any_en, Const(1, 1)
        else:
            wea, cea = be[0], Const(1, 1)
        if read_a is not None:
            wea, cea = zero, Const(1, 1)
        dia = di[:18] if w >= 18 else Cat(di[:9], Const(0, 9))
        dib = di[18:36] if w == 36 else Const(0, 18)
        params = {"p_DATA_WIDTH_A": w, "p_DATA_WIDTH_B": w,
                  "p_REGMODE_A": "OUTREG" if w == 36 or read_a is not None else "NOREG", "p_REGMODE_B": "OUTREG",
                  "p_RESETMODE": "SYNC", "p_ASYNC_RESET_RELEASE": "SYNC",
                  "p_CSDECODE_A": "0b000", "p_CSDECODE_B": "0b000",
                  "p_WRITEMODE_A": "NORMAL", "p_WRITEMODE_B": "NORMAL", "p_GSR": "AUTO"}
        if initvals is not None:
            for i, v in enumerate(initvals):
                params[f"p_INITVAL_{i:02X}"] = Const(v, 320)
        ports = {"i_CLKA": ClockSignal(), "i_CLKB": ClockSignal(), "i_CEA": cea, "i_WEA": wea,
                 "i_OCEA": Const(1, 1), "i_RSTA": zero, "i_CEB": Const(1, 1), "i_WEB": zero,
                 "i_OCEB": Const(1, 1), "i_RSTB": zero}
        for k in range(3):
            ports[f"i_CSA{k}"] = zero
            ports[f"i_CSB{k}"] = zero
        for k in range(14):
            ports[f"i_ADA{k}"] = ada[k]
            ports[f"i_ADB{k}"] = adb[k]
        for k in range(18):
            ports[f"i_DIA{k}"] = dia[k]
            ports[f"i_DIB{k}"] = dib[k]
        doa = Signal(18, name="doa")
        dob = Signal(18, name="dob")
        for k in range(18):
            ports[f"o_DOA{k}"] = doa[k]
            ports[f"o_DOB{k}"] = dob[k]
        inst = Instance("DP16KD", **params, **ports)
        sub = Module()
        sub.submodules.dp16kd = inst
        if w == 36:
            sub.d.comb += do.eq(Cat(doa, dob))
        else:
            sub.d.comb += do.eq(dob[:w])
        if read_a is not None:
            sub.d.comb += read_a[1].eq(doa[:w])
        return sub
