"""`LaneRom`: the per-item fields of a lane in one read-only BlockRam (read latency 2).

A lane declares fields (name, bits, one value per slot) as it builds its pipeline; the ROM packs them
into one word per slot, LSB first, and `field(name)` is that field of the word read two cycles after the
address, the value at the lane's ROM stage.
"""
from __future__ import annotations

import numpy as np
from amaranth.hdl import Signal, unsigned

from .bram import BlockRam


class LaneRom:
    def __init__(self, depth: int, ram: str):
        self.depth, self.ram = max(1, depth), ram
        self.fields: list[tuple[str, Signal, np.ndarray]] = []

    def add(self, name: str, shape, values) -> Signal:
        """A field (Amaranth shape) with one value per slot (shorter arrays are padded with 0)."""
        sig = Signal(shape, name=name)
        vals = np.zeros(self.depth, np.int64)
        arr = np.asarray(values, np.int64)
        vals[:len(arr)] = arr
        self.fields.append((name, sig, vals))
        return sig

    def build(self, m, name: str, addr):
        """The ROM as submodule `name`, addressed by `addr`; drives every field's signal."""
        if not self.fields:
            return None
        widths = [len(sig) for _, sig, _ in self.fields]
        words = []
        for n in range(self.depth):
            w, off = 0, 0
            for (_, _, vals), width in zip(self.fields, widths):
                w |= (int(vals[n]) & ((1 << width) - 1)) << off
                off += width
            words.append(w)
        rom = BlockRam(sum(widths), self.depth, init=words, writable=False, ram=self.ram)
        m.submodules[name] = rom
        m.d.comb += rom.r_addr.eq(addr)
        off = 0
        for (_, sig, _), width in zip(self.fields, widths):
            m.d.comb += sig.eq(rom.r_data[off:off + width])
            off += width
        return rom
