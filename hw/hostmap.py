"""The host's view of a core: its registers and the address map of its state memories, defined once.

No Amaranth here: the host driver (sim/host.py) and the cocotb testbench (sim/cocotb_core.py) import this
module in processes that have no hardware toolchain, the core (hw/core.py) decodes exactly these
addresses, and the manifest (hw/emit.py) states them.

Word addresses, 32-bit data. Register reads answer READ_LATENCY cycles after the request.

  0x000000  ID (read): ID_WORD, "RHE0"
  0x000001  RUN: write n > 0 to run n steps (busy at once); read: steps left
  0x000002  STATUS (read): bit 0 busy, bit 1 any saturation since the last clear
  0x000003  STEP: the step counter (read/write; loads act by step number)
  0x000004  SATURATIONS (read): saturation count (saturates at 2^32 - 1); write: clear count and flags
  0x000005  SATURATION_FLAGS (read): sticky flag per quantity (bit order in the manifest)
  0x000006  CYCLES (read): clock cycles spent running since reset
  NODE_BASE + (field << (word_bits + slot_bits)) + (slot << word_bits) + word
            node state: field 0..D-1 = x_k, D..2D-1 = u_k (raw, sign-extended); node n lives in memory
            `slot` at `word` (the core's placement, `HostMap.node_slot` / `node_word`)
  ELEM_BASE + (field << (pos_bits + lane_bits)) + (lane << pos_bits) + pos
            element state: field 0 = a (the only one); element e is item `pos` of element lane `lane`
"""
from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numpy as np

ID_WORD = 0x52484530
ADDR_BITS = 24
DATA_BITS = 32
READ_LATENCY = 3          # cycles from a read request to its answer
NODE_BASE, ELEM_BASE = 0x100000, 0x200000
ELEMENT_FIELDS = ("a",)   # element state words, in field order


class Reg(IntEnum):
    """Register addresses."""
    ID = 0
    RUN = 1
    STATUS = 2
    STEP = 3
    SATURATIONS = 4
    SATURATION_FLAGS = 5
    CYCLES = 6


STATUS_BUSY, STATUS_SATURATED = 1, 2     # STATUS bits


def field_bits(count: int) -> int:
    """Bits of an address field that counts `count` things (at least 1)."""
    return max(1, int(count - 1).bit_length())


@dataclass(frozen=True, eq=False)
class HostMap:
    """Where every node and element state word of one core sits in the host's address space.

    node_slot, node_word: (N,) the memory (slot) and word of each node; node_memories, node_words: how many
    memories and words per memory the core has. elem_lane, elem_pos, lanes, elem_slots: the same for
    elements over element lanes.
    """
    dim: int
    node_slot: np.ndarray
    node_word: np.ndarray
    node_memories: int
    node_words: int
    elem_lane: np.ndarray
    elem_pos: np.ndarray
    lanes: int
    elem_slots: int

    @classmethod
    def interleaved(cls, dim: int, n_nodes: int, node_lanes: int, n_elements: int, lanes: int) -> "HostMap":
        """Node n in memory n % Q at word n // Q; element e in lane e % P at position e // P."""
        n, e = np.arange(n_nodes), np.arange(n_elements)
        return cls(dim, n % node_lanes, n // node_lanes, node_lanes, -(-n_nodes // node_lanes),
                   e % lanes, e // lanes, lanes, -(-n_elements // lanes))

    @property
    def n_nodes(self) -> int:
        return len(self.node_slot)

    @property
    def n_elements(self) -> int:
        return len(self.elem_lane)

    @property
    def word_bits(self) -> int:
        return field_bits(self.node_words)

    @property
    def slot_bits(self) -> int:
        return field_bits(self.node_memories)

    @property
    def pos_bits(self) -> int:
        return field_bits(self.elem_slots)

    @property
    def lane_bits(self) -> int:
        return field_bits(self.lanes)

    @property
    def node_fields(self) -> int:
        return 2 * self.dim

    def node_addr(self, field: int, n) -> np.ndarray:
        """Host word address of node n's field (0..D-1: x_k, D..2D-1: u_k)."""
        n = np.asarray(n)
        return (NODE_BASE + (field << (self.word_bits + self.slot_bits)) + (self.node_slot[n] << self.word_bits)
                + self.node_word[n])

    def elem_addr(self, field: int, e) -> np.ndarray:
        """Host word address of element e's state field (0: a)."""
        e = np.asarray(e)
        return ELEM_BASE + (field << (self.pos_bits + self.lane_bits)) + (self.elem_lane[e] << self.pos_bits) + self.elem_pos[e]

    def node_addrs(self) -> list[np.ndarray]:
        """Every node's address, per node field."""
        n = np.arange(self.n_nodes)
        return [self.node_addr(f, n) for f in range(self.node_fields)]

    def elem_addrs(self) -> list[np.ndarray]:
        e = np.arange(self.n_elements)
        return [self.elem_addr(f, e) for f in range(len(ELEMENT_FIELDS))]

    def to_dict(self) -> dict:
        """The manifest's `host_interface`."""
        return {
            "addr_bits": ADDR_BITS, "data_bits": DATA_BITS, "read_latency_cycles": READ_LATENCY,
            "registers": {r.name: int(r) for r in Reg},
            "status_bits": {"busy": STATUS_BUSY, "saturated": STATUS_SATURATED},
            "id_word": ID_WORD, "node_base": NODE_BASE, "element_base": ELEM_BASE,
            "node_address": "node_base + (field << (word_bits + slot_bits)) + (slot << word_bits) + word",
            "element_address": "element_base + (field << (pos_bits + lane_bits)) + (lane << pos_bits) + pos",
            "node_fields": [f"x{k}" for k in range(self.dim)] + [f"u{k}" for k in range(self.dim)],
            "element_fields": list(ELEMENT_FIELDS),
            "word_bits": self.word_bits, "slot_bits": self.slot_bits, "pos_bits": self.pos_bits,
            "lane_bits": self.lane_bits,
        }
