"""The order of the streams, decided at scene-compile time (NumPy and SciPy only, no Amaranth).

1. Nodes are renumbered by reverse Cuthill-McKee (scipy.sparse.csgraph) over the graph whose edges are
   the elements and, for topology pairs, every two nodes of a pair (in a mesh those are element edges
   already): every element and pair then spans a short range of node numbers, the *bandwidth*.
2. Elements are sorted by (higher node, lower node), topology pairs by their nodes from the highest
   down: as the streams advance, the nodes they touch advance too, so a window of nodes slides along.
3. Item k of a stream runs in lane k % P at slot k // P of the step (`lane_items`).

The bit-true model's force sums are exact integers, so any order gives its bits: the hardware may stream
in this order and still equal the model bit for bit. The host addresses translate (`perm`, `position`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import reverse_cuthill_mckee


@dataclass(frozen=True, eq=False)
class StreamOrder:
    """A renumbering of the nodes and the order of the element and pair streams.

    perm[n]: the new number of original node n; inv[m]: the original node of new number m.
    elements[k]: the original element streamed k-th; ei[k], ej[k]: its nodes i, j in the new numbering
    (roles kept: i receives +fe, j -fe). pairs[k], pair_nodes[k]: the same for topology pairs (roles in
    columns: the vertex, then the facet's vertices). bandwidth: max |a - b| over the new numbers of any two
    nodes of one element or pair.
    """
    perm: np.ndarray
    inv: np.ndarray
    elements: np.ndarray
    ei: np.ndarray
    ej: np.ndarray
    pairs: np.ndarray
    pair_nodes: np.ndarray
    bandwidth: int

    @property
    def n_nodes(self) -> int:
        return len(self.perm)

    def element_position(self) -> np.ndarray:
        """position[e]: where original element e sits in the stream."""
        pos = np.empty(len(self.elements), np.int64)
        pos[self.elements] = np.arange(len(self.elements))
        return pos


def node_graph_edges(n_nodes: int, edges: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """(a, b) node pairs that must be close: every element, and every two nodes of a topology pair."""
    parts = [np.asarray(edges, np.int64).reshape(-1, 2)]
    pairs = np.asarray(pairs, np.int64)
    if pairs.size:
        for a in range(pairs.shape[1]):
            for b in range(a + 1, pairs.shape[1]):
                parts.append(pairs[:, [a, b]])
    e = np.concatenate(parts) if parts else np.zeros((0, 2), np.int64)
    return e[e[:, 0] != e[:, 1]]


def bandwidth(perm: np.ndarray, edges: np.ndarray) -> int:
    """max |perm[a] - perm[b]| over the given node pairs (0 without any)."""
    if not len(edges):
        return 0
    return int(np.abs(perm[edges[:, 0]] - perm[edges[:, 1]]).max())


def rcm_permutation(n_nodes: int, edges: np.ndarray) -> np.ndarray:
    """perm[n] = new number of node n by reverse Cuthill-McKee over the undirected graph `edges`."""
    if n_nodes == 0:
        return np.zeros(0, np.int64)
    a, b = edges[:, 0], edges[:, 1]
    g = coo_matrix((np.ones(2 * len(a)), (np.concatenate([a, b]), np.concatenate([b, a]))),
                   shape=(n_nodes, n_nodes)).tocsr()
    order = np.asarray(reverse_cuthill_mckee(g, symmetric_mode=True), np.int64)    # order[new] = old
    perm = np.empty(n_nodes, np.int64)
    perm[order] = np.arange(n_nodes)
    return perm


def stream_order(n_nodes: int, edges: np.ndarray, pairs: np.ndarray | None = None,
                 perm: np.ndarray | None = None) -> StreamOrder:
    """The renumbering (reverse Cuthill-McKee unless `perm` is given) and the sorted streams."""
    edges = np.asarray(edges, np.int64).reshape(-1, 2)
    pairs = np.zeros((0, 0), np.int64) if pairs is None else np.asarray(pairs, np.int64)
    graph = node_graph_edges(n_nodes, edges, pairs)
    if perm is None:
        perm = rcm_permutation(n_nodes, graph)
    perm = np.asarray(perm, np.int64)
    if sorted(perm.tolist()) != list(range(n_nodes)):
        raise ValueError("perm is not a permutation of the nodes")
    inv = np.empty(n_nodes, np.int64)
    inv[perm] = np.arange(n_nodes)
    ni, nj = perm[edges[:, 0]], perm[edges[:, 1]]
    el = np.lexsort((np.minimum(ni, nj), np.maximum(ni, nj)))        # by higher node, then lower node
    if pairs.size:
        pn = perm[pairs]
        keys = -np.sort(-pn, axis=1)                                   # each pair's nodes, highest first
        pr = np.lexsort(tuple(keys[:, c] for c in range(keys.shape[1] - 1, -1, -1)))
        pair_nodes = pn[pr]
    else:
        pr = np.zeros(0, np.int64)
        pair_nodes = np.zeros((0, pairs.shape[1] if pairs.ndim == 2 else 0), np.int64)
    return StreamOrder(perm, inv, el.astype(np.int64), ni[el], nj[el], pr.astype(np.int64), pair_nodes,
                       bandwidth(perm, graph))


def lane_items(n_items: int, lanes: int, lane: int) -> np.ndarray:
    """Stream positions that lane `lane` of `lanes` runs, in slot order: k = slot * lanes + lane."""
    return np.arange(lane, n_items, lanes)
