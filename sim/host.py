"""The host side of the accelerator's register interface (hw/hostmap.py): load a scene, run, read back.

Written once against a tiny asynchronous bus (`write(addr, data)`, `read_many(addrs)`, `wait(cycles)`),
so that Amaranth's simulator (sim/hwsim.py) and the cocotb testbenches on Icarus and Verilator
(sim/cocotb_core.py) drive the core the same way. The driver needs only the address lists, which a
`job` dict carries into a simulator process that has no scene at hand.
"""
from __future__ import annotations

import numpy as np

from hw.hostmap import STATUS_BUSY, HostMap, Reg


def to_signed32(v: int) -> int:
    v = int(v) & 0xFFFFFFFF
    return v - (1 << 32) if v & (1 << 31) else v


class HostDriver:
    def __init__(self, dim: int, node_addrs, elem_addrs, cycles_per_step: int, bus=None):
        self.dim, self.bus, self.cycles_per_step = int(dim), bus, int(cycles_per_step)
        self.on_cycles = None
        self.node_addrs = [np.asarray(a, np.int64) for a in node_addrs]      # 2D fields: x_k, u_k
        self.elem_addrs = [np.asarray(a, np.int64) for a in elem_addrs]      # element fields: a only
        if len(self.elem_addrs) != 1:
            raise ValueError(f"one element state field (a), got {len(self.elem_addrs)}")

    @classmethod
    def for_map(cls, host_map: HostMap, cycles_per_step: int, bus=None) -> "HostDriver":
        return cls(host_map.dim, host_map.node_addrs(), host_map.elem_addrs(), cycles_per_step, bus)

    def to_job(self) -> dict:
        return {"dim": self.dim, "cycles_per_step": self.cycles_per_step,
                "node_addrs": np.stack(self.node_addrs), "elem_addrs": np.stack(self.elem_addrs)}

    @classmethod
    def from_job(cls, job, bus=None) -> "HostDriver":
        return cls(int(job["dim"]), list(job["node_addrs"]), list(job["elem_addrs"]), int(job["cycles_per_step"]), bus)

    # ---- commands
    def load_words(self, X, U, A, step: int = 0) -> list[tuple[int, int]]:
        """The (address, data) writes that load a whole state (raw integers) and the step counter."""
        words = []
        for f, vals in enumerate(list(X) + list(U)):
            words += [(int(a), int(v)) for a, v in zip(self.node_addrs[f], np.asarray(vals))]
        words += [(int(a), int(v)) for a, v in zip(self.elem_addrs[0], np.asarray(A))]
        return words + [(Reg.STEP, int(step)), (Reg.SATURATIONS, 0)]      # the last write clears the saturations

    async def write_words(self, words):
        for addr, data in words:
            await self.bus.write(int(addr), int(data))

    async def load(self, X, U, A, step: int = 0):
        await self.write_words(self.load_words(X, U, A, step))

    WAIT_CHUNK = 20_000       # cycles: a long run is waited for in chunks, each reported to on_cycles

    async def run(self, steps: int) -> int:
        """Run `steps` steps and wait until the core is idle; returns the cycles the run took. While waiting,
        `self.on_cycles(n)` (if set) hears of every n cycles waited (progress of long runs)."""
        before = (await self.bus.read_many([Reg.CYCLES]))[0]
        await self.bus.write(Reg.RUN, int(steps))
        left = max(1, steps * self.cycles_per_step - 8)
        while left > 0:
            n = min(left, self.WAIT_CHUNK)
            await self.bus.wait(n)
            left -= n
            if self.on_cycles is not None:
                self.on_cycles(n)
        while (await self.bus.read_many([Reg.STATUS]))[0] & STATUS_BUSY:
            await self.bus.wait(4)
        after = (await self.bus.read_many([Reg.CYCLES]))[0]
        return (after - before) & 0xFFFFFFFF

    @property
    def read_addrs(self) -> list[int]:
        addrs = np.concatenate(self.node_addrs + self.elem_addrs + [np.array([Reg.STEP, Reg.SATURATIONS, Reg.SATURATION_FLAGS])])
        return [int(a) for a in addrs]

    async def read_raw(self) -> list[int]:
        return await self.bus.read_many(self.read_addrs)

    def decode(self, vals):
        """Raw read-back words -> (X list, U list, A, step, saturation count, flags)."""
        D = self.dim
        N, E = len(self.node_addrs[0]), len(self.elem_addrs[0])
        s = np.array([to_signed32(v) for v in vals], np.int64)
        nodes = [s[f * N:(f + 1) * N] for f in range(2 * D)]
        off = 2 * D * N
        A = s[off:off + E]
        step, sat, flags = (int(v) & 0xFFFFFFFF for v in vals[-3:])
        return nodes[:D], nodes[D:], A, step, sat, flags

    async def read_state(self):
        return self.decode(await self.read_raw())
