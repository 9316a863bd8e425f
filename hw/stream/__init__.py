"""The streaming core (issue 15, design C of docs hw-architecture review): node state stored once, the
element and pair streams in a bandwidth-reducing order reading their nodes from a sliding window, node
integration fused into the stream, steps back to back on a static schedule.

Modules, one concept each (no Amaranth in the first two):

  order.py      scene-compile-time order: reverse Cuthill-McKee renumbering, sorted streams, lanes
  schedule.py   StreamSchedule: every fill, read, contribution and retirement cycle, the window, the
                period T, checked against every read-after-write constraint at construction
  bram.py       BlockRam: a simple dual-port block RAM with its output register (Amaranth Memory, or
                ECP5 DP16KD instances with REGMODE_B = "OUTREG"), and the DP16KD model for simulators
  nodeword.py   how a node's x, u words pack into memory words
  store.py      NodeStore: node state, stored once in Q banks
  window.py     NodeWindow: the ring of nodes, one copy per read port, written by the fill
  forcering.py  ForceRing: a lane role's force accumulator (read-modify-write with forwarding)
  element.py    ElementLane, pair.py PairLane, node.py NodeLane: the per-item kernels of hw/datapath.py
  control.py    Control: the run, its prologue, periods and epilogue; hostport.py HostPort
  core.py       StreamCore: the top, composing the components; config.py StreamConfig
"""
