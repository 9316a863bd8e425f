"""Number formats of every quantity the hardware holds or computes, derived from the scene.

One place defines them: each quantity named in hw/datapath.py gets a fixed-point format here.
- Word widths come from a preset: `state` words (positions, velocities, a), `operand` words (multiplier
  inputs and products), and the node force accumulator (operand + `acc_guard` bits). The probe's forces
  (`probe_force`) sit at the node force's binary point with the integer bits their range needs, so that
  each node takes its probe force exactly and the probe's force is their exact integer sum.
- Binary points come from range analysis: the float datapath is run over the scene and the peak |value|
  of each quantity, times a headroom, sets its integer bits; the rest of the word is fraction.
  a, unit vectors and weights have fixed ranges ([0, 1] / [-1, 1]) and fixed formats.
- Parameters (k1, c1, ...) are constants fitted to their own value with operand-width words.
Function units are configured per preset too (1/sqrt by table or by Newton, its table size or seed bits and
Newton steps, inverse table size).
A scene may override any quantity's format in its [formats] table, e.g. `x = "SQ(2, 30)"`.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from enum import StrEnum

from .fixed import SQ, FormatError, Shape

# quantity -> (word class, what it is)
QUANTITIES = {
    "x": ("state", "position, length units"),
    "u": ("state", "velocity as displacement per step"),
    "dv": ("state", "velocity increment of a step (mu F)"),
    "a": ("fixed_state", "Voigt fraction of an element, in [0, 1]"),
    "d": ("operand", "edge vector component x_j - x_i"),
    "du": ("operand", "relative velocity component"),
    "l2": ("operand", "squared edge length"),
    "inv_l": ("operand", "1 / edge length (rsqrt unit)"),
    "l": ("operand", "edge length, and a l"),
    "e": ("fixed_operand", "unit vector component"),
    "ldot": ("operand", "stretch rate"),
    "s": ("operand", "Voigt extension a l - L"),
    "force": ("operand", "element tension T = Phi(Y) or Psi(W), k1 s, penalty forces"),
    "drive": ("operand", "element drive Y = k1 s + c1 ldot (the Voigt force with a rigid damper), c1 ldot"),
    "wdot": ("operand", "damper rates: w' = W(Y), (1 - a) ldot and their difference"),
    "adot": ("operand", "rate of a per step"),
    "sdot": ("operand", "a ldot (the Voigt part's stretch rate on the a_max stop)"),
    "fe": ("operand", "force vector component of an element or pair"),
    "facc": ("accumulator", "node force accumulator: fe's binary point, exact sums (internal forces cancel)"),
    "fnode": ("operand", "node force, multiplier operand of the per-node mass ratio"),
    "tr": ("operand", "topology: facet edge and vertex offsets"),
    "tl2": ("operand", "topology: squared lengths, dot products, cross product components"),
    "tl4": ("operand", "topology (3D): squared cross product and weight numerators"),
    "tinv": ("operand", "topology (2D): 1 / facet length"),
    "tinv2": ("operand", "topology (3D): 1 / |cross product|"),
    "tinv4": ("operand", "topology (3D): 1 / |cross product|^2"),
    "tdist": ("operand", "signed distances and projections"),
    "w": ("fixed_operand", "foot weights and ratios, in [0, 1]"),
    "cr": ("operand", "collision: facet edges and vertex offsets (any surface vertex to any facet)"),
    "cl2": ("operand", "collision: squared facet length (2D), cross product, dot products, projections"),
    "cl4": ("operand", "collision (3D): squared cross product and weight numerators"),
    "cinv": ("operand", "collision (2D): 1 / facet length"),
    "cinv2": ("operand", "collision (3D): 1 / |cross product|"),
    "cinv4": ("operand", "collision (3D): 1 / |cross product|^2"),
    "cdist": ("operand", "collision: signed distances to the facet and projections along it"),
    "fmag2": ("operand", "friction: squared tangential force"),
    "finv": ("operand", "friction: 1 / |tangential force|"),
    "pr": ("operand", "probe: node offset x - p inside the probe's bounding box (|x_k - p_k| < R)"),
    "pr2": ("operand", "probe: squared distance |x - p|^2 (the gate |x - p|^2 < R^2)"),
    "pinv": ("operand", "probe: 1 / |x - p| (rsqrt unit)"),
    "pdist": ("operand", "probe: distance |x - p| and penetration R - |x - p|"),
    "pdu": ("operand", "probe: node velocity relative to the probe, its normal and tangential parts"),
    "psample": ("operand", "probe: displacement over one device sample, p - p_prev"),
    "pdot": ("operand", "probe: velocity (p - p_prev) / k, as displacement per step"),
    "pforce": ("operand", "probe: normal force N on a node, mu N, friction"),
    "pfmag2": ("operand", "probe friction (3D): squared tangential force"),
    "pfinv": ("operand", "probe friction (3D): 1 / |tangential force|"),
    "pfe": ("probe_force", "probe: force component on a node, at the node force's binary point (enters facc exactly)"),
    "fprobe": ("probe_force", "probe: the force on the probe, minus the exact sum of the node probe forces"),
}
# quantities that share another's format
ALIASES: dict = {}
# constants: fitted to their own value (the damper's: c2 and the slopes of Phi, W and Psi on their
# linear pieces, hw/datapath.py)
CONSTANTS = {"L": "l", "k1": None, "c1": None, "c1a": None, "c2": None, "phi_s": None, "ic12": None,
             "phi_lo": None, "phi_hi": None, "rate_lo": None, "rate_hi": None, "psi_lo": None, "psi_hi": None,
             "eps": None, "topo_K": None, "topo_C": None,
             "floor_K": None, "floor_C": None, "floor_kf": None, "mu": None, "inv_mass": None, "g": None,
             "coll_h": None, "coll_K": None, "coll_C": None, "coll_kf": None,
             "probe_R": None, "probe_R2": None, "probe_K": None, "probe_C": None, "probe_kf": None, "inv_k": None,
             "load": "facc"}

# every quantity and constant name as a checked constant: kernels write Q.l2, and a misspelt name is an
# AttributeError where it is written (tests/test_house.py also checks every Q.name in the kernels' source)
Q = StrEnum("Q", {name: name for name in (*QUANTITIES, *CONSTANTS)})


@dataclass(frozen=True)
class Preset:
    name: str
    state: int
    operand: int
    acc_guard: int = 6
    headroom_bits: int = 2
    rsqrt_seed_bits: int = 9
    rsqrt_newton: int = 1
    # 1/sqrt by table and interpolation (hw/funcunits.py RsqrtTable, 2^S segments) instead of Newton
    # (Rsqrt: seed ROM and rsqrt_newton steps): S, or 0 for Newton. The table needs one multiplier where
    # a Newton step needs three to four; it is used where its error bound fits the output format
    # (hw/bittrue.py function_units), Newton elsewhere
    rsqrt_table_segments_log2: int = 0
    damper_segments_log2: int = 6
    description: str = ""


FORMAT_PRESETS = {
    "narrow": Preset("narrow", 18, 18, rsqrt_seed_bits=9, rsqrt_newton=1, rsqrt_table_segments_log2=10,
                     damper_segments_log2=6,
                     description="DSP-native: 18-bit words everywhere (one 18x18 multiplier per product)"),
    "medium": Preset("medium", 27, 18, rsqrt_seed_bits=9, rsqrt_newton=1, rsqrt_table_segments_log2=10,
                     damper_segments_log2=8, description="27-bit states, 18-bit multiplier operands"),
    "wide": Preset("wide", 32, 32, rsqrt_seed_bits=10, rsqrt_newton=2, damper_segments_log2=10,
                   description="32-bit states and operands"),
}


def _int_bits(peak: float, headroom_bits: int) -> int:
    """Integer bits (with sign) holding +/- peak * 2^headroom_bits."""
    if peak <= 0 or not math.isfinite(peak):
        return 1
    return math.floor(math.log2(peak)) + 1 + headroom_bits + 1


def fit(value_peak: float, width: int, headroom_bits: int = 0) -> Shape:
    i = _int_bits(value_peak, headroom_bits)
    return SQ(i, width - i)


_SHAPE_RE = re.compile(r"^\s*(SQ|UQ)\s*\(\s*(-?\d+)\s*,\s*(-?\d+)\s*\)\s*$")


def parse_shape(text: str) -> Shape:
    m = _SHAPE_RE.match(str(text))
    if not m:
        raise FormatError(f"format must look like SQ(i, f) or UQ(i, f), got {text!r}")
    from .fixed import UQ
    return (SQ if m.group(1) == "SQ" else UQ)(int(m.group(2)), int(m.group(3)))


STAGNATION_LSBS = 2.0     # a state whose typical per-step increment is below this many LSBs stagnates
# state -> (what its per-step increment is, the quantity whose LSB it is measured against)
STAGNATION_STATES = {"x": "v dt (the displacement of a step)", "u": "F dt / m (the velocity change of a step)",
                     "a": "adot dt (the change of a of a step)"}




@dataclass
class FormatSet:
    preset: Preset
    shapes: dict = field(default_factory=dict)      # quantity -> Shape
    peaks: dict = field(default_factory=dict)       # quantity -> peak |value| seen in range analysis
    increments: dict = field(default_factory=dict)  # state -> typical per-step increment in range analysis

    def stagnation(self, min_lsbs: float = STAGNATION_LSBS) -> list[dict]:
        """States whose typical per-step increment (the median over the range analysis's steps of the
        largest increment of any item) is below `min_lsbs` LSBs of their format: round to nearest then
        loses the motion (MODEL.md section 8), so creep, sinking or recovery silently vanish."""
        out = []
        for q, inc in self.increments.items():
            if q in self.shapes and inc > 0.0:
                lsb = self.shapes[q].lsb
                if inc < min_lsbs * lsb:
                    out.append({"quantity": q, "increment": inc, "lsb": lsb, "lsbs": inc / lsb,
                                "what": STAGNATION_STATES.get(q, q)})
        return out

    def __getitem__(self, q) -> Shape:
        return self.shapes[ALIASES.get(q, q)]

    def __contains__(self, q) -> bool:
        return ALIASES.get(q, q) in self.shapes

    def keys(self):
        return list(self.shapes) + list(ALIASES)

    def to_dict(self) -> dict:
        return {q: {**s.to_dict(), "format": str(s), "peak": self.peaks.get(q)} for q, s in self.shapes.items()}


def derive(peaks: dict, preset: Preset, overrides: dict | None = None, increments: dict | None = None) -> FormatSet:
    """Formats for every quantity seen in the range analysis (`peaks`: quantity -> max |value|);
    `increments`: the states' typical per-step increments, kept for `FormatSet.stagnation`."""
    fs = FormatSet(preset, peaks=dict(peaks), increments=dict(increments or {}))
    ws, wo = preset.state, preset.operand
    for q, (cls, _) in QUANTITIES.items():
        if q not in peaks and q not in ("a", "e", "w"):
            continue
        peak = max(peaks.get(q, 0.0), peaks.get(next((k for k, v in ALIASES.items() if v == q), ""), 0.0))
        if cls == "state":
            fs.shapes[q] = fit(peak, ws, preset.headroom_bits)
        elif cls == "fixed_state":
            fs.shapes[q] = SQ(2, ws - 2)
        elif cls == "fixed_operand":
            fs.shapes[q] = SQ(2, wo - 2)
        elif cls in ("accumulator", "probe_force"):
            pass                                    # below: derived from the element force format
        else:
            fs.shapes[q] = fit(peak, wo, preset.headroom_bits)
    if "facc" in peaks:
        fe = fs.shapes.get("fe") or fit(peaks["facc"], wo, preset.headroom_bits)
        i_acc = max(fe.i, _int_bits(peaks["facc"], preset.headroom_bits)) + preset.acc_guard
        fs.shapes["facc"] = SQ(i_acc, fe.f)
    for q, guard in (("pfe", 0), ("fprobe", preset.acc_guard)):
        if q in peaks:
            f = fs.shapes["fe"].f if "fe" in fs.shapes else wo - _int_bits(peaks[q], preset.headroom_bits)
            fs.shapes[q] = SQ(_int_bits(peaks[q], preset.headroom_bits) + guard, f)
    for q, like in CONSTANTS.items():
        if q not in peaks:
            continue
        if like is not None and like in fs.shapes:
            fs.shapes[q] = fs.shapes[like]
        else:
            width = ws if q == "g" else wo
            fs.shapes[q] = fit(peaks[q], width, 0)
    for q, shape in check_overrides(overrides or {}).items():
        fs.shapes[q] = shape
    return fs


def check_scene_formats(system) -> dict:
    """Validate a scene's [formats] table (golden keeps it as given); a problem raises FormatError naming
    the scene and the table."""
    try:
        return check_overrides(system.formats)
    except ValueError as exc:
        raise FormatError(f"scene '{system.name}': [formats] {exc}") from None


def check_overrides(overrides: dict) -> dict:
    """Validate a scene's [formats] table: quantity -> "SQ(i, f)"; returns quantity -> Shape."""
    if not isinstance(overrides, dict):
        raise ValueError("must be a table of quantity = \"SQ(i, f)\"")
    out = {}
    for q, text in overrides.items():
        if q not in QUANTITIES and q not in CONSTANTS:
            raise ValueError(f"unknown quantity '{q}' (known: {', '.join(sorted(QUANTITIES))})")
        shape = text if isinstance(text, Shape) else parse_shape(text)
        if shape.width > 32:
            raise ValueError(f"'{q}' = {shape}: at most 32 bits")
        out[q] = shape
    return out
