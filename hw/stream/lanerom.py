"""`LaneRom`: the per-item fields of a lane in one read-only BlockRam (read latency 2), optionally
dictionary-encoded.

A lane declares fields (name, shape, one value per slot) and builds the ROM; each field's signal is its
value for the slot addressed two cycles before (the lane's ROM stage). With `dictionary=True` the
encoding is decided by the values (the scene decides the hardware):

- a field with a single value over the slots is a constant: no ROM bits;
- fields with 2..DICT_ENTRIES distinct values are grouped, first fit in declaration order, into
  dictionaries of at most DICT_ENTRIES distinct value tuples; the ROM stores a tuple's index
  (ceil(log2 n) bits) and a constant table after the ROM's output register decodes it. DICT_ENTRIES = 16:
  an index of at most 4 bits makes every decoded bit one LUT4 of registered bits (one logic level, no
  carry, no multiplexer tree), so the fields stay valid at the ROM stage;
- a group not narrower than its fields stored plainly, and every other field, is stored plainly.

Slots beyond the values given (the ROM is as deep as the longest lane) hold index 0 or zeros; lanes
never use them. Cost: `bits` per slot (the sum of plain widths and index widths), DP16KD from
`plan_blocks`, one LUT4 per decoded bit. `encoding()` lists the plan.
"""
from __future__ import annotations

import numpy as np
from amaranth.hdl import Const, Mux, Signal

from .bram import BlockRam, ram_record

DICT_ENTRIES = 16


def _index_bits(n: int) -> int:
    return max(1, (n - 1).bit_length())


class LaneRom:
    def __init__(self, depth: int, ram: str, dictionary: bool = False):
        self.depth, self.ram, self.dictionary = max(1, depth), ram, dictionary
        self.fields: list[tuple[str, Signal, np.ndarray]] = []
        self._plan = None

    def add(self, name: str, shape, values) -> Signal:
        """A field (Amaranth shape) with one value per slot (the first len(values) slots)."""
        sig = Signal(shape, name=name)
        mask = (1 << len(sig)) - 1
        vals = np.array([int(v) & mask for v in np.asarray(values, np.int64)], dtype=object)
        self.fields.append((name, sig, vals))
        self._plan = None
        return sig

    def signal(self, name: str) -> Signal:
        return next(sig for n, sig, _ in self.fields if n == name)

    # ---- the encoding
    def plan(self):
        """(constants, plain, groups): constants [(field index, value)], plain [field index], groups
        [([field indices], [value tuples])], a field index into `fields`."""
        if self._plan is not None:
            return self._plan
        consts, plain, groups = [], [], []
        for k, (_, sig, vals) in enumerate(self.fields):
            distinct = set(vals.tolist())
            if self.dictionary and len(distinct) <= 1:
                consts.append((k, next(iter(distinct)) if distinct else 0))
            elif self.dictionary and len(distinct) <= DICT_ENTRIES:
                for members in groups:
                    if len(self._tuples(members + [k])) <= DICT_ENTRIES:
                        members.append(k)
                        break
                else:
                    groups.append([k])
            else:
                plain.append(k)
        kept = []
        for members in groups:
            tuples = self._tuples(members)
            if _index_bits(len(tuples)) < sum(len(self.fields[k][1]) for k in members):
                kept.append((members, tuples))
            else:
                plain += members
        self._plan = (consts, sorted(plain), kept)
        return self._plan

    def _tuples(self, members):
        """The distinct value tuples of fields `members` over the slots with values, in first-seen order."""
        n = min(len(self.fields[k][2]) for k in members)
        return list(dict.fromkeys(tuple(self.fields[k][2][s] for k in members) for s in range(n)))

    @property
    def bits(self) -> int:
        _, plain, groups = self.plan()
        return sum(len(self.fields[k][1]) for k in plain) + sum(_index_bits(len(t)) for _, t in groups)

    def encoding(self) -> dict:
        """field name -> "const", "plain" or "dict<g>" (group g), and the word's bits."""
        consts, plain, groups = self.plan()
        out = {self.fields[k][0]: "const" for k, _ in consts}
        out.update({self.fields[k][0]: "plain" for k in plain})
        for g, (members, _) in enumerate(groups):
            out.update({self.fields[k][0]: f"dict{g}" for k in members})
        return out

    def records(self, name: str) -> list[dict]:
        """The memory inventory entry of the ROM (none if every field is a constant)."""
        return [ram_record(name, self.bits, self.depth)] if self.fields and self.bits else []

    def words(self) -> list[int]:
        """The ROM's words: plain fields, then the groups' indices, LSB first."""
        _, plain, groups = self.plan()
        cols = [(self.fields[k][2], len(self.fields[k][1])) for k in plain]
        for members, tuples in groups:
            index = {t: i for i, t in enumerate(tuples)}
            n = min(len(self.fields[k][2]) for k in members)
            cols.append((np.array([index[tuple(self.fields[k][2][s] for k in members)] for s in range(n)],
                                  dtype=object), _index_bits(len(tuples))))
        words = [0] * self.depth
        off = 0
        for vals, width in cols:
            for s, v in enumerate(vals):
                words[s] |= int(v) << off
            off += width
        return words

    def build(self, m, name: str, addr):
        """The ROM as submodule `name`, addressed by `addr`; drives every field's signal."""
        if not self.fields:
            return None
        consts, plain, groups = self.plan()
        for k, v in consts:
            sig = self.fields[k][1]
            m.d.comb += sig.eq(Const(v, len(sig)))
        if not self.bits:
            return None
        rom = BlockRam(self.bits, self.depth, init=self.words(), writable=False, ram=self.ram)
        m.submodules[name] = rom
        m.d.comb += rom.r_addr.eq(addr)
        off = 0
        for k in plain:
            sig = self.fields[k][1]
            m.d.comb += sig.eq(rom.r_data[off:off + len(sig)])
            off += len(sig)
        for members, tuples in groups:
            ib = _index_bits(len(tuples))
            index = rom.r_data[off:off + ib]
            off += ib
            # the decode: constants chosen by the index, one LUT4 per bit after synthesis; a chain of
            # Mux, not a Switch, so that the Verilog is continuous assignments (a process that only wakes
            # on a change of its input would leave X in event-driven simulators until the index changes)
            for j, k in enumerate(members):
                sig = self.fields[k][1]
                value = Const(tuples[-1][j], len(sig))
                for i in range(len(tuples) - 2, -1, -1):
                    value = Mux(index == i, Const(tuples[i][j], len(sig)), value)
                m.d.comb += sig.eq(value)
        return rom
