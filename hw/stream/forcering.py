"""`ForceRing`: one lane role's force accumulator, a ring of exact sums with a copy for the node lanes.

Every element lane has one for node i and one for node j, every pair lane one per role. A contribution
(`add`: the node's ring slot, its window slot mod Wr = `ring_groups`, and bank, D raw words in the "fe"
format) is presented in cycle t, the
cycle its pipeline stage reads the ring (stage s of the lane); its sum is written at t + RMW (RMW = 3,
hw/stream/schedule.py):

  t      the ring word at (slot, bank) is read (block RAM, data at t + 2)
  t + 1  flags: did the items one, two, three ahead write this word?  (registered compares, a copy of
         the flags per dimension: each drives one dimension's acc_bits multiplexers)
  t + 2  old = 0 if this is the lane's first contribution to the node in this step (`first`), else the
         sum of the nearest item ahead (one, two or three) that wrote this word, else the word read;
         new = old + value (exact, `acc_bits` bits per dimension), registered
  t + 3  the registered sum is written into the ring and into segment `bank` of the node lanes' copy
         (slot `slot`)

The register between the sum and the block RAM's write port keeps the loop of a read-modify-write off
one cycle: the block RAM may sit far from its adder (nextpnr on the 1e3 square, medium: 12.7 ns of
routing out of and back into one DP16KD in a cycle, 65.6 MHz, when the sum was written unregistered).
The items one to three ahead write in the cycles of this item's read and the two before it, which the
read cannot see (and the one in its cycle is undefined on a block RAM): their sums come from registers
instead. The
`first` flag makes a ring that is never cleared: the word a node takes over still holds the sum of the
node that had the slot before (Wr Q nodes earlier), and the schedule guarantees the node lanes read that sum
before this write (hw/stream/schedule.py). II = 1, no stalls; a sum is in the node copy, readable,
RMW + 1 cycles after its contribution was presented.

`node_addr` (a slot) reads the node copy: `node_data`, LATENCY = 2 cycles later, holds the Q nodes' sums
of the group in that slot (segment q: node q of the group, D words of `acc_bits`). With `lut_copy` set
the node copy is LUT RAM (`BlockRam(distributed=True)`, the same latency): it is Wg words deep, a
quarter of a block's depth or less.
"""
from __future__ import annotations

from amaranth.hdl import Cat, Module, Mux, Signal, signed
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

from ..rtl_fixed import KEEP_APART_TAG
from .bram import LATENCY, BlockRam, ram_record
from .nodeword import bits_for, delay
from .schedule import RMW


def ContributionSignature(dim: int, fe_bits: int, node_lanes: int, ring_groups: int):
    """A lane's contribution port, from the lane's side: `first` / `last`: the lane's first / last
    contribution to this node in this step (`last` is used by RunSum only)."""
    return wiring.Signature({"valid": Out(1), "slot": Out(bits_for(ring_groups)), "bank": Out(bits_for(node_lanes)),
                             "first": Out(1), "last": Out(1), "value": Out(dim * fe_bits)})


class ForceRing(wiring.Component):
    def __init__(self, dim: int, fe_bits: int, acc_bits: int, node_lanes: int, ring_groups: int,
                 ram: str = "sim"):
        if acc_bits < fe_bits:
            raise ValueError(f"accumulator of {acc_bits} bits narrower than its {fe_bits}-bit contributions")
        self.D, self.fe_bits, self.acc_bits, self.Q, self.Wr, self.ram = dim, fe_bits, acc_bits, node_lanes, ring_groups, ram
        self.rmw, self.latency = RMW, LATENCY
        self.lut_copy = False                  # the node copy in LUT RAM (StreamCore's block RAM fit)
        self.qbits, self.wbits = bits_for(node_lanes), bits_for(ring_groups)
        super().__init__({
            "add": In(ContributionSignature(dim, fe_bits, node_lanes, ring_groups)),
            "node_addr": In(self.wbits),
            "node_data": Out(node_lanes * dim * acc_bits),
        })

    def _shapes(self):
        """(width, depth, segments) of the read-modify-write ring and of the node lanes' copy."""
        ring_depth = self.Wr << (self.qbits if self.Q > 1 else 0)
        return (self.D * self.acc_bits, ring_depth, 1), (self.Q * self.D * self.acc_bits, self.Wr, self.Q)

    def rams(self, name: str) -> list[dict]:
        (w1, d1, s1), (w2, d2, s2) = self._shapes()
        return [ram_record(f"ring_{name}", w1, d1, s1),
                ram_record(f"ring_{name}_node_copy", w2, d2, s2, distributed=self.lut_copy)]

    def memories(self):
        """(read-modify-write ring, node lanes' copy)."""
        return tuple(BlockRam(w, d, segments=s, ram=self.ram, distributed=lut)
                     for (w, d, s), lut in zip(self._shapes(), (False, self.lut_copy)))

    def elaborate(self, platform):
        m = Module()
        D, A, F = self.D, self.acc_bits, self.fe_bits
        ring, copy = self.memories()
        m.submodules.ring, m.submodules.copy = ring, copy
        add = self.add
        word0 = Cat(add.bank, add.slot) if self.Q > 1 else add.slot
        m.d.comb += ring.r_addr.eq(word0)
        assert RMW == 3, "the forwarding below covers the three items ahead of a read"
        word1 = delay(m, word0, 1, "word1", data=True)
        words = {1: word1}
        for k in range(2, 5):
            words[k] = delay(m, words[k - 1], 1, f"word{k}", data=True)
        en = {2: delay(m, add.valid, 2, "valid2")}
        for k in range(3, 5):
            en[k] = delay(m, en[k - 1], 1, f"valid{k}")
        first1 = delay(m, add.first, 1, "first")
        value2 = delay(m, add.value, 2, "value", data=True)
        slot3, bank3 = delay(m, add.slot, 3, "slot", data=True), delay(m, add.bank, 3, "bank", data=True)
        # forwarding flags for the item now at t + 2: did the item j ahead (j = 1, 2, 3) write its word?
        # Registered compares at t + 1, of this item's word (word1) and the item j ahead's (word 1 + j),
        # a copy per dimension (kept apart): each selects acc_bits multiplexers, not D acc_bits
        hits = {j: en[1 + j] & (word1 == words[1 + j]) for j in (1, 2, 3)}
        sums = []
        for k in range(D):
            fwd = {j: Signal(name=f"fwd{j}_{k}{KEEP_APART_TAG}") for j in (1, 2, 3)}
            first2 = Signal(name=f"first2_{k}{KEEP_APART_TAG}")
            m.d.sync += [fwd[j].eq(hits[j]) for j in (1, 2, 3)] + [first2.eq(first1)]
            rd = ring.r_data[k * A:(k + 1) * A].as_signed()
            last = {j: Signal(signed(A), name=f"last{j}_{k}", reset_less=True) for j in (1, 2, 3)}   # sums 1, 2, 3 ahead
            new = Signal(signed(A), name=f"sum_{k}")
            old = Mux(first2, 0, Mux(fwd[1], last[1], Mux(fwd[2], last[2], Mux(fwd[3], last[3], rd))))
            m.d.comb += new.eq(old + value2[k * F:(k + 1) * F].as_signed())
            m.d.sync += [last[1].eq(new), last[2].eq(last[1]), last[3].eq(last[2])]
            sums.append(last[1])                  # at t + 3: this item's sum, registered
        word = Cat(*sums)
        m.d.comb += [ring.w_addr.eq(words[3]), ring.w_data.eq(word), ring.w_en.eq(en[3]),
                     copy.w_addr.eq(slot3), copy.w_data.eq(word.replicate(self.Q)),
                     copy.w_en.eq(Cat(*[en[3] & (bank3 == q) for q in range(self.Q)])),
                     copy.r_addr.eq(self.node_addr), self.node_data.eq(copy.r_data)]
        return m


class RunSum(wiring.Component):
    """A lane role whose contributions to a node arrive as one run of consecutive items: an element
    lane's higher node (the element stream is sorted by higher node, so a lane's items with the same
    higher node follow one another). The run is summed in a register, and its total is written once, at
    the run's last item (`last`), into the node lanes' copy: no read-modify-write ring. Same ports and
    timing as ForceRing: the total of a run whose last item is presented in cycle t is written at
    t + RMW, readable from t + RMW + 1.

      t      sum = (0 if `first` else the running sum) + value; the running sum takes it
      t + 1  the sum, registered (RMW - 1 registers in all)
      t + 3  written into segment `bank` of slot `slot` of the node copy if the item was a run's last
    """

    def __init__(self, dim: int, fe_bits: int, acc_bits: int, node_lanes: int, ring_groups: int,
                 ram: str = "sim"):
        self.D, self.fe_bits, self.acc_bits, self.Q, self.Wr, self.ram = dim, fe_bits, acc_bits, node_lanes, ring_groups, ram
        self.rmw, self.latency = RMW, LATENCY
        self.lut_copy = False                  # as ForceRing's
        super().__init__({
            "add": In(ContributionSignature(dim, fe_bits, node_lanes, ring_groups)),
            "node_addr": In(bits_for(ring_groups)),
            "node_data": Out(node_lanes * dim * acc_bits),
        })

    def _shape(self):
        return self.Q * self.D * self.acc_bits, self.Wr, self.Q

    def rams(self, name: str) -> list[dict]:
        return [ram_record(f"runsum_{name}_node_copy", *self._shape(), distributed=self.lut_copy)]

    def elaborate(self, platform):
        m = Module()
        D, A, F = self.D, self.acc_bits, self.fe_bits
        w, d, s = self._shape()
        copy = BlockRam(w, d, segments=s, ram=self.ram, distributed=self.lut_copy)
        m.submodules.copy = copy
        add = self.add
        sums = []
        for k in range(D):
            acc, new = Signal(signed(A), name=f"acc_{k}", reset_less=True), Signal(signed(A), name=f"sum_{k}")
            m.d.comb += new.eq(Mux(add.first, 0, acc) + add.value[k * F:(k + 1) * F].as_signed())
            with m.If(add.valid):
                m.d.sync += acc.eq(new)
            sums.append(new)
        word2 = delay(m, Cat(*sums), RMW, "sum", data=True)
        write2 = delay(m, add.valid & add.last, RMW, "write")
        slot2, bank2 = delay(m, add.slot, RMW, "slot", data=True), delay(m, add.bank, RMW, "bank", data=True)
        m.d.comb += [copy.w_addr.eq(slot2), copy.w_data.eq(word2.replicate(self.Q)),
                     copy.w_en.eq(Cat(*[write2 & (bank2 == q) for q in range(self.Q)])),
                     copy.r_addr.eq(self.node_addr), self.node_data.eq(copy.r_data)]
        return m
