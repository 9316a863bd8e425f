"""sim.synth: Yosys + nextpnr-ecp5 on a small Amaranth design (18x18 MAC + 512x18 block RAM).

Runs the real tools (YoWASP). The first call of each tool compiles its WebAssembly (about a minute,
cached afterwards in the user cache directory); later runs of this file take about 20 s.
"""

import json

import pytest
from amaranth import Cat, Const, Module, Signal, signed
from amaranth.back import verilog
from amaranth.lib import wiring
from amaranth.lib.memory import Memory
from amaranth.lib.wiring import In, Out

from sim.synth import DEVICES, SynthesisError, _log_utilisation, synthesize

pytestmark = pytest.mark.slow      # `make test-fast` leaves these out


class MacRam(wiring.Component):
    """Registered signed 18x18 multiply-accumulate (with clear) and a 512x18 RAM read synchronously."""
    a: In(signed(18))
    b: In(signed(18))
    clear: In(1)
    addr: In(9)
    we: In(1)
    wdata: In(18)
    acc: Out(signed(48))
    q: Out(18)

    def elaborate(self, platform):
        m = Module()
        m.submodules.mem = mem = Memory(shape=18, depth=512, init=[])
        rd, wr = mem.read_port(), mem.write_port()
        m.d.comb += [rd.addr.eq(self.addr), wr.addr.eq(self.addr), wr.en.eq(self.we), wr.data.eq(self.wdata)]
        ra, rb = Signal(signed(18)), Signal(signed(18))
        prod = Signal(signed(36))
        acc = Signal(signed(48))
        clr = Signal()
        m.d.sync += [ra.eq(self.a), rb.eq(self.b), prod.eq(ra * rb), clr.eq(self.clear)]
        with m.If(clr):
            m.d.sync += acc.eq(prod)
        with m.Else():
            m.d.sync += acc.eq(acc + prod)
        q = Signal(18)
        m.d.sync += q.eq(rd.data ^ self.wdata)          # some LUT logic after the RAM
        m.d.comb += [self.acc.eq(acc), self.q.eq(q)]
        return m


class ManyMults(wiring.Component):
    """29 registered 18x18 products: one more than the 28 multipliers of a 25k ECP5."""
    x: In(signed(18))
    o: Out(36 * 29)

    def elaborate(self, platform):
        m = Module()
        regs = [Signal(signed(18), name=f"r{i}") for i in range(30)]
        prods = [Signal(signed(36), name=f"p{i}") for i in range(29)]
        m.d.sync += regs[0].eq(self.x)
        for i in range(29):
            m.d.sync += [regs[i + 1].eq(regs[i]), prods[i].eq(regs[i] * regs[i + 1])]
        m.d.comb += self.o.eq(Cat(*prods))
        return m


@pytest.fixture(scope="module")
def mac_verilog(tmp_path_factory):
    d = tmp_path_factory.mktemp("mac_src")
    p = d / "mac_ram.v"
    p.write_text(verilog.convert(MacRam(), name="mac_ram"))
    return p


@pytest.fixture(scope="module")
def mac_result(mac_verilog, tmp_path_factory):
    out = tmp_path_factory.mktemp("mac_out")
    return out, synthesize(mac_verilog, "mac_ram", out, device="ecp5-85k", clock_mhz=50.0)


def test_mac_design_resources_fmax_and_reports(mac_result):
    out, r = mac_result
    assert r["device"] == "ecp5-85k" and r["top"] == "mac_ram" and r["router"] == "router1"
    assert r["mult18x18"] >= 1
    assert r["block_rams"] >= 1
    assert r["luts"] > 0
    assert r["flip_flops"] > 0
    assert r["carry_cells"] > 0                       # the 48-bit accumulator adder
    assert r["clock_constraint_mhz"] == 50.0
    assert r["fmax_mhz"] is not None and r["fmax_mhz"] > 0
    assert r["clock_found"] and "clk" in r["clock_net"]
    assert r["timing_met"] is (r["fmax_mhz"] >= 50.0)
    # Yosys counts and nextpnr utilisation agree
    u = r["utilization"]
    assert u["MULT18X18D"]["used"] == r["mult18x18"] == r["yosys_cells"]["MULT18X18D"]
    assert u["DP16KD"]["used"] == r["block_rams"] == r["yosys_cells"]["DP16KD"]
    assert u["TRELLIS_FF"]["used"] == r["flip_flops"] == r["yosys_cells"]["TRELLIS_FF"]
    assert u["TRELLIS_COMB"]["used"] >= r["luts"] + 2 * r["carry_cells"]
    assert u["TRELLIS_COMB"]["available"] == 83640 and u["DP16KD"]["available"] == 208
    # ports other than the clock are not pads: only the clock pin is used
    assert u["TRELLIS_IO"]["used"] == 1
    assert r["io"]["top_port_bits"] > u["TRELLIS_IO"]["used"]
    assert set(r["wall_s"]) == {"yosys", "nextpnr"} and all(v > 0 for v in r["wall_s"].values())
    assert r["tool_versions"]["yosys"].startswith("Yosys ")
    assert r["tool_versions"]["nextpnr-ecp5"] != "unknown"

    # the utilisation table of the nextpnr log (used when nextpnr fails) parses to the same figures
    assert _log_utilisation((out / "nextpnr.log").read_text()) == u

    # synth.json is the returned dict
    for name in ("synth.json", "report.md", "yosys.log", "nextpnr.log", "nextpnr-report.json", "mac_ram.json"):
        assert (out / name).stat().st_size > 0, name
    assert json.loads((out / "synth.json").read_text()) == r
    # report.md states the same figures
    md = (out / "report.md").read_text()
    assert f"Fmax {r['fmax_mhz']:.1f} MHz" in md and "constraint 50 MHz" in md
    assert ("timing **met**" if r["timing_met"] else "timing **NOT met**") in md
    assert f"| {u['MULT18X18D']['used']} | {u['MULT18X18D']['available']} |" in md
    assert f"| {u['DP16KD']['used']} | {u['DP16KD']['available']} | " \
           f"{100 * u['DP16KD']['used'] / u['DP16KD']['available']:.1f} |" in md
    assert f"LUT4 {r['luts']}," in md and f"TRELLIS_FF {r['flip_flops']}," in md

    # the worst path is the one nextpnr's Fmax comes from; every endpoint pin is counted
    cp = r["critical_path"]
    assert cp["delay_ns"] == pytest.approx(1000.0 / r["fmax_mhz"], abs=0.01), (cp, r["fmax_mhz"])
    assert cp["logic_ns"] + cp["routing_ns"] == pytest.approx(cp["delay_ns"], abs=0.002)
    assert cp["routing_ns"] > 0 and cp["cells"] >= 1 and cp["longest_route"]["delay_ns"] <= cp["routing_ns"]
    late = r["late_endpoints"]
    assert late["period_ns"] == 20.0 and late["endpoints"] > 0
    assert (late["late"] == 0) is r["timing_met"]
    assert f"Critical path: `{cp['from']}` -> `{cp['to']}`, {cp['delay_ns']:.2f} ns" in md
    assert f"**{late['late']}** of {late['endpoints']}" in md


def test_missed_constraint_is_reported_not_raised(mac_verilog, tmp_path, capsys):
    r = synthesize(mac_verilog, "mac_ram", tmp_path, device="ecp5-45k", clock_mhz=1000.0, progress=True,
                   router="router2")
    assert r["timing_met"] is False and r["router"] == "router2"
    assert 0 < r["fmax_mhz"] < 1000.0
    assert r["utilization"]["TRELLIS_COMB"]["available"] == 43848
    assert "timing **NOT met**" in (tmp_path / "report.md").read_text()
    err = capsys.readouterr().err.splitlines()
    # one line per step, with elapsed time; a slow nextpnr (a loaded machine) also says when it has placed
    steps = [ln for ln in err if "] nextpnr: placed (" not in ln]
    assert len(steps) == 3 and len(err) <= 4, err
    assert all(ln.startswith("[synth ") and " s] " in ln for ln in err), err
    assert "] yosys: " in steps[0] and "] nextpnr: Fmax " in steps[1] and "] reports written to " in steps[2]


def test_unknown_router_is_refused_before_any_tool(mac_verilog, tmp_path):
    with pytest.raises(ValueError, match="unknown nextpnr router 'router3' .*router1, router2"):
        synthesize(mac_verilog, "mac_ram", tmp_path, router="router3")
    with pytest.raises(ValueError, match="unknown nextpnr placer 'sa' .*heap, static"):
        synthesize(mac_verilog, "mac_ram", tmp_path, placer="sa")
    assert not any(tmp_path.iterdir())


def test_unknown_device_lists_known_ones(mac_verilog, tmp_path):
    with pytest.raises(ValueError) as e:
        synthesize(mac_verilog, "mac_ram", tmp_path, device="ice40-up5k")
    msg = str(e.value)
    assert "ice40-up5k" in msg
    for name in DEVICES:
        assert name in msg
    assert set(DEVICES) >= {"ecp5-12k", "ecp5-25k", "ecp5-45k", "ecp5-85k"}
    assert not any(tmp_path.iterdir())                # rejected before any tool ran


def test_verilog_syntax_error_raises_synthesis_error(tmp_path):
    bad = tmp_path / "bad.v"
    bad.write_text("module bad(input clk, output reg q);\n  always @(posedge clk) q <= ;\nendmodule\n")
    with pytest.raises(SynthesisError) as e:
        synthesize(bad, "bad", tmp_path / "out")
    msg = str(e.value)
    assert isinstance(e.value, RuntimeError)
    assert msg.startswith("yosys failed")
    assert "syntax error" in msg and "bad.v:2" in msg     # the tail of the Yosys log
    assert "Traceback" not in msg


def test_design_that_does_not_fit(tmp_path):
    src = tmp_path / "many.v"
    src.write_text(verilog.convert(ManyMults(), name="many"))
    with pytest.raises(SynthesisError) as e:
        synthesize(src, "many", tmp_path / "out", device="ecp5-25k")
    msg = str(e.value)
    assert "does not fit ecp5-25k" in msg
    assert "29 of 28 MULT18X18D" in msg


def test_yosys_only_gives_resources_without_fmax(mac_verilog, mac_result, tmp_path):
    """place_and_route=False: the same Yosys cell counts as the full flow, no nextpnr, no Fmax."""
    _, full = mac_result
    r = synthesize(mac_verilog, "mac_ram", tmp_path, device="ecp5-85k", clock_mhz=50.0, place_and_route=False)
    assert r["place_and_route"] is False and r["fmax_mhz"] is None and r["timing_met"] is None
    for k in ("luts", "flip_flops", "mult18x18", "block_rams", "carry_cells"):
        assert r[k] == full[k], k
    assert r["utilization"]["MULT18X18D"] == {"used": full["mult18x18"], "available": 156}
    assert not (tmp_path / "nextpnr.log").exists() and r["wall_s"]["nextpnr"] is None
    md = (tmp_path / "report.md").read_text()
    assert "no place and route" in md and "MHz" not in md
    assert json.loads((tmp_path / "synth.json").read_text()) == r


class SharedOperand(wiring.Component):
    """Two products of one operand through `registered_product`: each multiplier's operand register holds
    the same value, which Yosys would merge into one flip-flop feeding both DSP blocks."""
    x: In(signed(18))
    y: In(signed(18))
    z: In(signed(18))
    o: Out(72)

    def __init__(self, dsp: str = "sim"):
        self.dsp = dsp
        super().__init__()

    def elaborate(self, platform):
        from hw.rtl_fixed import registered_product
        m = Module()
        p, _ = registered_product(m, self.x, self.y, "p", self.dsp)
        q, _ = registered_product(m, self.x, self.z, "q", self.dsp)
        m.d.comb += self.o.eq(Cat(p, q))
        return m


def test_operand_registers_of_multipliers_stay_apart(tmp_path):
    """Each multiplier keeps its own operand registers (hw/rtl_fixed.py KEEP_APART_TAG): 4 x 18 operand
    bits and 2 x 2 x 36 product bits (pipelined_product's register, registered_product's), 216 flip-flops;
    with x's two copies merged there would be 198."""
    src = tmp_path / "shared.v"
    src.write_text(verilog.convert(SharedOperand(), name="shared"))
    r = synthesize(src, "shared", tmp_path / "out", device="ecp5-85k", place_and_route=False)
    assert r["mult18x18"] == 2
    assert r["flip_flops"] == 4 * 18 + 4 * 36, r["flip_flops"]


def test_instantiated_multipliers_hold_their_registers(tmp_path):
    """The "ecp5" variant of the same two products (hw/mult18x18d.py): every register lives in the two
    MULT18X18D blocks (input, pipeline, output), none in the fabric, and nextpnr is told so (the cells'
    REG_*_CLK parameters in Yosys' netlist)."""
    src = tmp_path / "shared.v"
    src.write_text(verilog.convert(SharedOperand("ecp5"), name="shared"))
    r = synthesize(src, "shared", tmp_path / "out", device="ecp5-85k", place_and_route=False)
    assert r["mult18x18"] == 2 and r["flip_flops"] == 0, r
    cells = json.loads((tmp_path / "out" / "shared.json").read_text())["modules"]["shared"]["cells"].values()
    dsps = [c["parameters"] for c in cells if c["type"] == "MULT18X18D"]
    assert len(dsps) == 2
    for prm in dsps:
        assert [prm[f"REG_{r}_CLK"].strip() for r in ("INPUTA", "INPUTB", "PIPELINE", "OUTPUT")] == ["CLK0"] * 4, prm


class Distributed(wiring.Component):
    """Two distributed BlockRams, 32 x 84 in two segments (force-ring node copies under narrow), written
    alike (as the window's copies are), each with its own read port."""

    def __init__(self, ram):
        self.ram = ram
        super().__init__({"w_addr": In(5), "w_data": In(84), "w_en": In(2), "r_addr": In(5).array(2),
                          "r_data": Out(84).array(2)})

    def elaborate(self, platform):
        from hw.stream.bram import BlockRam
        m = Module()
        for k in range(2):
            m.submodules[f"mem{k}"] = mem = BlockRam(84, 32, segments=2, ram=self.ram, distributed=True)
            m.d.comb += [mem.w_addr.eq(self.w_addr), mem.w_data.eq(self.w_data), mem.w_en.eq(self.w_en),
                         mem.r_addr.eq(self.r_addr[k]), self.r_data[k].eq(mem.r_data)]
        return m


def test_distributed_block_ram_maps_to_lut_ram(tmp_path):
    """Yosys puts a `distributed` BlockRam in TRELLIS_DPR16X4 (per 42-bit segment 11 columns of 4 bits, x 2
    rows of 16 words), no DP16KD; each copy keeps its own write registers (5 + 84 + 2 flip-flops: merged,
    one decoder would serve copies far apart), its registered read address (5) and output register (84)."""
    src = tmp_path / "lut.v"
    src.write_text(verilog.convert(Distributed("ecp5"), name="lut"))
    r = synthesize(src, "lut", tmp_path / "out", device="ecp5-85k", place_and_route=False)
    assert r["block_rams"] == 0 and r["distributed_rams"] == 2 * (2 * 11 * 2), r
    assert r["flip_flops"] == 2 * ((5 + 84 + 2) + 5 + 84), r


class RegisteredCopies(wiring.Component):
    """Two 72 x 128 BlockRams with registered inputs (two 512 x 36 DP16KD each), written alike and read
    apart, as the window's node read copies are."""

    def __init__(self):
        super().__init__({"w_addr": In(7), "w_data": In(72), "w_en": In(1), "r_addr": In(7).array(2),
                          "r_data": Out(72).array(2)})

    def elaborate(self, platform):
        from hw.stream.bram import BlockRam
        m = Module()
        for k in range(2):
            m.submodules[f"mem{k}"] = mem = BlockRam(72, 128, ram="ecp5", registered=True)
            m.d.comb += [mem.w_addr.eq(self.w_addr), mem.w_data.eq(self.w_data), mem.w_en.eq(self.w_en),
                         mem.r_addr.eq(self.r_addr[k]), self.r_data[k].eq(mem.r_data)]
        return m


def test_registered_block_ram_keeps_a_register_set_per_block(tmp_path):
    """Every DP16KD of a `registered` BlockRam keeps its own write address (7), enable (1), read address
    (7) and data slice (36) flip-flops: 4 x 51; merged by Yosys, one register feeds blocks placed far
    apart (checked without the tag: 7 + 1 + 2 x 7 + 72 = 94 flip-flops)."""
    src = tmp_path / "regcopies.v"
    src.write_text(verilog.convert(RegisteredCopies(), name="regcopies"))
    r = synthesize(src, "regcopies", tmp_path / "out", device="ecp5-85k", place_and_route=False)
    assert r["block_rams"] == 4, r
    assert r["flip_flops"] == 4 * (7 + 1 + 7 + 36), r["flip_flops"]


class DelayLines(wiring.Component):
    """LINE_GROUP + 1 8-bit values, each delayed 10 stages by a pipeline (hw/pipeline.py): as many delay
    lines of one span, in two groups."""

    def __init__(self):
        from hw.pipeline import LINE_GROUP
        self.n = LINE_GROUP + 1
        super().__init__({"a": In(8 * self.n), "o": Out(8 * self.n)})

    def elaborate(self, platform):
        from hw.pipeline import PipeArith
        m = Module()
        ar = PipeArith(m, {}, {}, Const(1, 1), "lane")
        m.d.comb += self.o.eq(Cat(*(ar.delay(self.a[8 * k:8 * k + 8], 0, 10) for k in range(self.n))))
        return m


def test_delay_line_groups_keep_their_own_addresses(tmp_path):
    """A group of LINE_GROUP delay lines shares a write and a read address counter (4 + 4 flip-flops),
    kept apart from the next group's; each line has its output register (8) and its LUT RAM (2
    TRELLIS_DPR16X4): 2 x 8 + 9 x 8 flip-flops; one counter pair for all would be 8 fewer, a counter pair
    a line 56 more (checked: 144)."""
    dut = DelayLines()
    src = tmp_path / "lines.v"
    src.write_text(verilog.convert(dut, name="lines"))
    r = synthesize(src, "lines", tmp_path / "out", device="ecp5-85k", place_and_route=False)
    assert r["distributed_rams"] == 2 * dut.n, r
    assert r["flip_flops"] == 2 * (4 + 4) + dut.n * 8, r["flip_flops"]


class NarrowDelays(wiring.Component):
    """Six flags and two 6-bit values, each delayed 10 stages by a pipeline: the scatter's slots and flags."""

    def __init__(self):
        super().__init__({"a": In(18), "o": Out(18)})

    def elaborate(self, platform):
        from hw.pipeline import PipeArith
        m = Module()
        ar = PipeArith(m, {}, {}, Const(1, 1), "lane")
        parts = [self.a[k:k + 1] for k in range(6)] + [self.a[6:12].as_signed(), self.a[12:18].as_signed()]
        m.d.comb += self.o.eq(Cat(*(ar.delay(v, 0, 10) for v in parts)))
        return m


def test_narrow_delay_lines_share_one_lut_ram(tmp_path):
    """Delay lines of one group and span are packed side by side (hw/pipeline.py PackedLines): the 18 bits
    of six flags and two 6-bit values take 5 TRELLIS_DPR16X4, where a line each took 6 + 2 x 2 = 10; each
    line keeps its output register (18 flip-flops) beside one write and one read counter (4 + 4)."""
    src = tmp_path / "narrow.v"
    src.write_text(verilog.convert(NarrowDelays(), name="narrow"))
    r = synthesize(src, "narrow", tmp_path / "out", device="ecp5-85k", place_and_route=False)
    assert r["distributed_rams"] == 5, r
    assert r["flip_flops"] == 18 + 4 + 4, r["flip_flops"]


def test_force_ring_registers_its_flags_per_dimension(tmp_path):
    """A force ring's forwarding flags (did the item 1, 2, 3 ahead write this word?) and its `first`
    flag are registered once per dimension, kept apart in Yosys: each drives one dimension's acc_bits
    multiplexers (one flag fed all D acc_bits, the 1e3 poke's critical path: 10.9 ns of routing)."""
    from hw.stream.forcering import ForceRing
    dut = ForceRing(dim=2, fe_bits=20, acc_bits=24, node_lanes=2, ring_groups=64, ram="ecp5")
    src = tmp_path / "ring.v"
    src.write_text(verilog.convert(dut, name="ring"))
    synthesize(src, "ring", tmp_path / "out", device="ecp5-85k", place_and_route=False)
    netlist = json.loads((tmp_path / "out" / "ring.json").read_text())
    nets, cells = netlist["modules"]["ring"]["netnames"], netlist["modules"]["ring"]["cells"].values()
    driven = {c["connections"]["Q"][0] for c in cells if c["type"] == "TRELLIS_FF"}
    for flag in ("fwd1", "fwd2", "fwd3", "first2"):
        bits = [nets[f"{flag}_{k}_keep_apart"]["bits"][0] for k in (0, 1)]
        assert all(b in driven for b in bits) and bits[0] != bits[1], (flag, bits)


@pytest.fixture(scope="module")
def stream_netlist(tmp_path_factory):
    """The streaming core of gravity-2d-linear (2 element lanes, 2 pair lanes, DP16KD) after Yosys: its
    top module's netnames and cells."""
    from hw import emit
    from conftest import bittrue
    tmp_path = tmp_path_factory.mktemp("stream")
    man = emit.write(bittrue("gravity-2d-linear", "narrow"), tmp_path, lanes=2, core="stream", ram="ecp5")
    synthesize(tmp_path / man["verilog"], man["top"], tmp_path / "out", device="ecp5-85k", place_and_route=False)
    top = json.loads((tmp_path / "out" / f"{man['top']}.json").read_text())["modules"][man["top"]]
    return top["netnames"], top["cells"]


def test_each_lane_registers_its_own_issue(stream_netlist):
    """The streaming core's issue (slot, base, valid) is registered in each lane (hw/stream/schedule.py
    ISSUE_FANOUT), each copy kept apart: after Yosys the two element lanes' slot registers are two sets of
    flip-flops, not one set feeding both lanes across the die. Amaranth names each register after the
    lane port it drives, the tagged name an alias: the script's `%a` (sim/synth.py) follows it. Each
    force ring registers the retirement's slot for its node copy the same way (RETIRE_FANOUT), each
    element lane the host's access to its a memory (ELEM_FANOUT) and the node store its own (NODE_FANOUT:
    Yosys once merged it with element lane 0's, which then lost its copy)."""
    nets, cells = stream_netlist
    drivers = {}                                      # flip-flop output bit -> the cell
    for c in cells.values():
        if c["type"] == "TRELLIS_FF":
            drivers[c["connections"]["Q"][0]] = c
    slot = {lane: nets[f"el{lane}.issue__slot"]["bits"] for lane in (0, 1)}   # each lane's issue port
    assert all(b in drivers for b in slot[0] + slot[1])
    assert not set(slot[0]) & set(slot[1])
    host = {lane: nets[f"el{lane}.host_wdata"]["bits"] + nets[f"el{lane}.host_pos"]["bits"] for lane in (0, 1)}
    store = nets["store.h_wdata"]["bits"] + nets["store.h_addr"]["bits"]   # the store's copy, apart too
    assert all(b in drivers for b in host[0] + host[1] + store)
    assert not set(host[0]) & set(host[1]) and not set(store) & (set(host[0]) | set(host[1]))
    # each force ring's node copy (DP16KD) reads at flip-flops of its own, none shared with another ring
    readers = {}                                      # flip-flop -> the rings whose node copy it addresses
    for name, c in cells.items():
        ring, _, rest = name.partition(".")
        if c["type"] == "DP16KD" and ring.startswith("ring_") and rest.startswith("copy."):
            for pin, bits in c["connections"].items():
                if pin.startswith("ADB") and bits[0] not in ("0", "1"):
                    assert bits[0] in drivers, (name, pin)
                    readers.setdefault(drivers[bits[0]]["connections"]["Q"][0], set()).add(ring)
    assert len(set.union(*readers.values())) == 10    # 2 element lanes x 2 roles, 2 pair lanes x 3
    assert all(len(r) == 1 for r in readers.values())


def test_only_control_state_has_a_reset(stream_netlist):
    """Data registers have no reset (hw/pipeline.py, hw/stream/nodeword.py `delay(data=True)`): only valid
    bits, strobes, counters and the control's state do. Before, 10,972 of this core's 15,344 flip-flops
    sat on the reset net (the 1e4 square: 21,900, one net across the die); now about 1,200, and no
    pipeline value, delay line or window word among them."""
    nets, cells = stream_netlist
    rst = nets["rst"]["bits"][0]
    ffs = {name: c for name, c in cells.items() if c["type"] == "TRELLIS_FF"}
    on_reset = [name for name, c in ffs.items() if c["connections"]["LSR"] == [rst]]
    assert len(on_reset) < 0.1 * len(ffs), (len(on_reset), len(ffs))
    values = ("_line_", "_dly_", "_mul_", "_sel_", "_sub_", "_add_", "_neg_", "fill_data", "ring_i__data", "_lines")
    assert not [n for n in on_reset if any(v in n for v in values)], [n for n in on_reset if any(v in n for v in values)][:5]


def test_memory_writes_are_registered_beside_their_memory(stream_netlist):
    """An element lane's new a and the node lanes' store write each go through a register of their own
    (hw/stream/schedule.py A_WRITE, STORE_WRITE) and then only the pipeline/host multiplexer, one LUT, into
    the block RAM's write port: each of those flip-flops feeds that LUT alone, so the placer can put it
    beside the memory (the 1e4 square at f6412ba: 73 late pins on the a memories' ports, 57 on the store's)."""
    nets, cells = stream_netlist
    driver, fanout = {}, {}
    for name, c in cells.items():
        for pin, d in c["port_directions"].items():
            for b in c["connections"][pin]:
                if d == "output":
                    driver[b] = (name, c)
                else:
                    fanout[b] = fanout.get(b, 0) + 1
    for memory, registers in (("el0.el0_a.", ("el0.el0_a_wdata_d1", "el0.el0_a_waddr_d1")),
                              ("el1.el1_a.", ("el1.el1_a_wdata_d1", "el1.el1_a_waddr_d1")),
                              ("store.bank0.", ("store.bank0_wr_data_d1", "store.bank0_wr_addr_keep_apart_d1"))):
        mine = {b for r in registers for b in nets[r]["bits"] if b not in ("0", "1")}
        assert mine and all(driver[b][1]["type"] == "TRELLIS_FF" and fanout[b] == 1 for b in mine), memory
        reached = set()                   # what reaches the write pins (port A; B's data too, 36 bits wide) via one LUT
        for name, c in cells.items():
            if c["type"] == "DP16KD" and name.startswith(memory):
                for pin, bits in c["connections"].items():
                    if pin.startswith(("DIA", "DIB", "ADA")) and bits[0] not in ("0", "1"):
                        lut = driver[bits[0]][1]
                        assert lut["type"] == "LUT4", (name, pin, lut["type"])
                        reached |= {lut["connections"][p][0] for p in "ABCD"} & mine
        assert reached == mine, (memory, len(mine - reached))
