"""`TablePair`: the function units' ROMs (1/sqrt table, Phi and Psi tables) shared by two lanes of a kind.

The tables are read-only and the same in every lane of a kind (element lanes; pair lanes), and a DP16KD
has two read ports: lanes 2k and 2k + 1 (`share`) read one copy, the first on port 1 (`r_addr`), the second on port 2 (`r2_addr`) of a two-port BlockRam
(hw/stream/bram.py; "ecp5": DP16KD in true dual-port mode with both output registers). The latency is
the units' own (address to registered word: two cycles), so the pipelines and their results do not
change. A table is shared when one two-port copy takes fewer blocks than two one-port copies
(`shares`): true dual-port mode has no 36-bit width, so a table of at most 512 words stays in each lane
(under medium the Phi tables, 256 x 31 and 256 x 34; Yosys may put such small ROMs in logic), while the
1/sqrt table (1024 x 35: 2 DP16KD instead of 4) and the Psi table (4096 x 34: 8 instead of 16) are
shared. Cost under medium: 10 shared DP16KD per pair of lanes plus 2 per lane, 14 per pair instead of 24.

Each unit asks `side.read(...)` for its tables in elaboration order; the two lanes run the same kernel,
so their n-th requests are the same table. The lane of side 0 elaborates first (the core adds it first)
and builds each ROM in its unit; side 1's n-th request takes port 2 of side 0's n-th ROM. `reset()` (at
each elaboration of the lane of side 0) starts a new set, so a core can be elaborated more than once.
"""
from __future__ import annotations

from .bram import BlockRam, plan_blocks, ram_record


def shares(width: int, depth: int) -> bool:
    """One two-port copy of a width x depth table takes fewer DP16KD than two one-port copies."""
    one, two = plan_blocks(width, depth), plan_blocks(width, depth, read_ports=2)
    return two[2] * two[3] < 2 * one[2] * one[3]


def share(lanes, ram: str):
    """Give lanes 2k and 2k + 1 the two sides of a TablePair (their `tables`); an odd last lane keeps its own."""
    for k in range(0, len(lanes) - 1, 2):
        lanes[k].tables, lanes[k + 1].tables = TablePair(ram).sides


def records(lane, name: str) -> list[dict]:
    """The inventory entries of the tables a lane holds for its pair (side 0; none otherwise)."""
    if lane.tables is None or lane.tables.side:
        return []
    return [ram_record(f"{name}.{mem['name'].split('_', 2)[2]}", mem["width"], mem["depth"], read_ports=2)
            for mem in lane.unit_memories() if shares(mem["width"], mem["depth"])]


class TablePair:
    def __init__(self, ram: str):
        self.ram = ram
        self.roms: list[BlockRam] = []
        self.sides = (TableSide(self, 0), TableSide(self, 1))


class TableSide:
    """One lane's view of a TablePair: `read` as hw/rtl_funcunits.py `_Pipe.table` calls it."""

    def __init__(self, pair: TablePair, side: int):
        self.pair, self.side, self.n = pair, side, 0

    def reset(self):
        self.n = 0
        if self.side == 0:
            self.pair.roms = []

    def read(self, m, name: str, width: int, words: list[int], addr):
        """ROM `name` of `width` bits and `words` read at `addr` (in unit module `m`): its registered word
        two cycles later; None for a table not worth sharing (the unit builds its own)."""
        if not shares(width, len(words)):
            return None
        n, self.n = self.n, self.n + 1
        if self.side == 0:
            rom = BlockRam(width, len(words), init=words, writable=False, read_ports=2, ram=self.pair.ram)
            self.pair.roms.append(rom)
            m.submodules[f"shared_{name}"] = rom
            m.d.comb += rom.r_addr.eq(addr)
            return rom.r_data
        if n >= len(self.pair.roms):
            raise AssertionError("a shared table's second lane elaborated before its first")
        rom = self.pair.roms[n]
        mask = (1 << width) - 1
        assert rom.width == width and rom.init == [w & mask for w in words], f"shared table {name}: lanes differ"
        m.d.comb += rom.r2_addr.eq(addr)
        return rom.r2_data
