"""Modelled energy and latency from counted operations, for machines without a readable counter.

Every figure made here is a *model*: counted operations times published per-operation costs.
Each constant carries its source (see shared/notes/anchors.md beside the repository) and every result says
``modelled (constants: ...)``. Two models:

Host (CPU/GPU, von Neumann), compute-and-SRAM energy in the style of Horowitz (ISSCC 2014, 45 nm):

    E_host = n_mac_fp32 * 4.6 pJ + n_add_fp32 * 0.9 pJ + n_add_int32 * 0.1 pJ + n_mul_int32 * 3.1 pJ
             + n_op_int8 * 0.03 pJ + bytes_sram / 8 * 10 pJ

(10 pJ per 64-bit SRAM read is the low end of Horowitz's 10-100 pJ; DRAM traffic, control and
static power are left out, so E_host is a lower bound on what a CPU really spends.)

Loihi 2 neuro cores (per-op figures published for Loihi, Davies et al. IEEE Micro 2018 Table 2;
no per-op figures have been published for Loihi 2, so these are applied as they are):

    E_loihi = n_synop * 23.6 pJ + n_update_active * 81 pJ + n_update_inactive * 52 pJ + n_spike * 1.7 pJ
    T_ts    = max over cores c of (inactive_c * 5.3 ns + active_c * 8.4 ns + synop_c * 3.5 ns) + barrier
    L       = sum over the B steps (and over sequential stages) of T_ts

Neurons are placed on cores in raster order, 8192 per core (1M neurons on 128 cores: the
paper's chip capacity and Intel's Loihi 2 brief). A neuron update is *active* when the neuron
receives input, holds a non-zero state or spikes in that step. Check against the paper: DOTIE's
one 640x480 layer gives about 16 uJ and 44 us per step here, i.e. 0.08 mJ and 0.22 ms for B = 5,
beside the measured 0.083 mJ / 0.29 ms of Table 2.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Iterable

import cv2
import numpy as np


@dataclass(frozen=True)
class Constant:
    value: float
    unit: str
    source: str


HOROWITZ = "Horowitz, ISSCC 2014, 45 nm"
DAVIES = "Davies et al., IEEE Micro 2018, Table 2 (Loihi)"

CONSTANTS: dict[str, Constant] = {
    "fp32_mac": Constant(4.6, "pJ", HOROWITZ + " (3.7 mult + 0.9 add)"),
    "fp32_add": Constant(0.9, "pJ", HOROWITZ),
    "int32_add": Constant(0.1, "pJ", HOROWITZ),
    "int32_mul": Constant(3.1, "pJ", HOROWITZ),
    "int8_op": Constant(0.03, "pJ", HOROWITZ + " (8-bit add)"),
    "sram_read_64b": Constant(10.0, "pJ", HOROWITZ + " (low end of 10-100 pJ per 64-bit SRAM read)"),
    "loihi_synop_e": Constant(23.6, "pJ", DAVIES),
    "loihi_synop_t": Constant(3.5, "ns", DAVIES),
    "loihi_update_inactive_e": Constant(52.0, "pJ", DAVIES),
    "loihi_update_inactive_t": Constant(5.3, "ns", DAVIES),
    "loihi_update_active_e": Constant(81.0, "pJ", DAVIES),
    "loihi_update_active_t": Constant(8.4, "ns", DAVIES),
    "loihi_spike_e": Constant(1.7, "pJ", DAVIES + " (spike within a tile)"),
    "loihi_barrier_t": Constant(465.0, "ns", DAVIES + " (upper end of 113-465 ns per time step)"),
    "loihi2_neurons_per_core": Constant(8192, "neurons", "1M neurons per chip (TOFFE paper) / 128 cores (Intel Loihi 2 brief)"),
    "loihi2_cores_per_chip": Constant(128, "cores", "Intel Loihi 2 brief"),
}

HOST_LABEL = "modelled (constants: Horowitz ISSCC 2014 45 nm per-op energies, 10 pJ per 64-bit SRAM read)"
LOIHI_LABEL = ("modelled (constants: Loihi per-op energy/time, Davies et al. IEEE Micro 2018; "
               "8192 neurons/core; 465 ns barrier)")


def c(name: str) -> float:
    return CONSTANTS[name].value


# ------------------------------------------------------------------------------ host op counts
@dataclass
class HostOps:
    """Operations one inference performs on a von Neumann machine (counts, not times)."""

    mac_fp32: float = 0.0
    add_fp32: float = 0.0          # adds, subtractions and comparisons in float
    add_int32: float = 0.0
    mul_int32: float = 0.0
    op_int8: float = 0.0           # byte/boolean operations (morphology, masks)
    sram_bytes: float = 0.0        # bytes read or written once per pass

    def __add__(self, other: "HostOps") -> "HostOps":
        return HostOps(**{f.name: getattr(self, f.name) + getattr(other, f.name) for f in dataclasses.fields(self)})

    def scaled(self, s: float) -> "HostOps":
        return HostOps(**{f.name: getattr(self, f.name) * s for f in dataclasses.fields(self)})

    def energy_j(self) -> float:
        pj = (self.mac_fp32 * c("fp32_mac") + self.add_fp32 * c("fp32_add") + self.add_int32 * c("int32_add")
              + self.mul_int32 * c("int32_mul") + self.op_int8 * c("int8_op")
              + self.sram_bytes / 8.0 * c("sram_read_64b"))
        return pj * 1e-12

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def mean_ops(ops: Iterable[HostOps]) -> HostOps:
    ops = list(ops)
    total = HostOps()
    for o in ops:
        total = total + o
    return total.scaled(1.0 / max(len(ops), 1))


def dense_conv_ops(h: int, w: int, c_in: int, c_out: int, k: int, steps: int = 1, in_bytes: int = 4) -> HostOps:
    """A dense KxK convolution over an (H, W) image, ``steps`` times: one MAC per tap per output."""
    n = h * w * steps
    return HostOps(mac_fp32=n * c_in * c_out * k * k, sram_bytes=n * (c_in * in_bytes + c_out * 4))


def dense_lif_ops(n_neurons: int, steps: int = 1) -> HostOps:
    """Float LIF over every neuron: decay-and-add (1 MAC), reset subtraction and threshold (2 adds);
    state read + write and spike write per neuron."""
    n = n_neurons * steps
    return HostOps(mac_fp32=n, add_fp32=2 * n, sram_bytes=n * 9)


def event_conv_ops(synops: float) -> HostOps:
    """Event-driven integer conv: one int32 accumulate (read-modify-write of 4 B) per synaptic op."""
    return HostOps(add_int32=synops, sram_bytes=synops * 8)


def fixed_lif_ops(n_updates: float) -> HostOps:
    """Fixed-point LIF on updated neurons only: decay multiply, add input, subtract reset, compare."""
    return HostOps(mul_int32=n_updates, add_int32=3 * n_updates, sram_bytes=n_updates * 17)


def morphology_ops(h: int, w: int, kernel: int, passes: int) -> HostOps:
    """Binary erode/dilate with a square kernel, separable (rows then columns): 2K byte ops per
    pixel per pass, one byte read + write per pixel per direction."""
    n = h * w * passes
    return HostOps(op_int8=n * 2 * kernel, sram_bytes=n * 4)


def event_index_ops(n_events: int) -> HostOps:
    """``events.binning.event_bin_index``: per event its bin (t - t0) * B // dt and linear index
    ((b * 2 + p) * H + y) * W + x, about 6 integer ops; 16 B of event read, 8 B of index written."""
    return HostOps(add_int32=6 * n_events, sram_bytes=24 * n_events)


def sort_unique_ops(n: int) -> HostOps:
    """np.unique of n int64 keys: a sort of ~n log2 n comparisons, 8 B read and written per
    comparison level."""
    if n < 2:
        return HostOps()
    levels = math.log2(n)
    return HostOps(add_int32=n * levels, sram_bytes=16 * n * levels)


def mask_ops(n_elements: int) -> HostOps:
    """Element-wise boolean AND / NOT over ``n_elements`` bytes."""
    return HostOps(op_int8=n_elements, sram_bytes=2 * n_elements)


def dbscan_ops(n_points: int, n_neighbour_pairs: int, leaf_size: int = 30) -> HostOps:
    """DBSCAN on 2-D points with a kd-tree (scikit-learn's choice for 2-D):

    tree build ~ n log2(n) comparisons; each query descends log2(n / leaf) nodes and scans at
    least its result set (the eps-neighbours, counted exactly): a 2-D squared distance is 2 MACs
    + 2 float ops (subtractions/compare) and reads 8 B of coordinates; cluster expansion touches
    each neighbour index once more (int op + 8 B read).
    """
    n = max(n_points, 1)
    logn = math.log2(n) if n > 1 else 1.0
    depth = max(math.log2(max(n / leaf_size, 1.0)), 1.0)
    tree = HostOps(add_fp32=n * logn, sram_bytes=n * logn * 8)
    queries = HostOps(add_fp32=n * depth * 2, sram_bytes=n * depth * 16)
    dist = HostOps(mac_fp32=2 * n_neighbour_pairs, add_fp32=2 * n_neighbour_pairs, sram_bytes=8 * n_neighbour_pairs)
    expand = HostOps(add_int32=n_neighbour_pairs, sram_bytes=8 * n_neighbour_pairs)
    return tree + queries + dist + expand if n_points else HostOps()


def onnx_macs(onnx_path, batch: int = 1) -> dict:
    """MACs of one inference of an ONNX model (Conv, ConvTranspose, Gemm, MatMul nodes), counted
    from the graph's inferred shapes. Returns {"macs", "by_op", "params" (initializer elements),
    "activations" (output elements of the counted nodes)}."""
    import onnx
    from onnx import shape_inference

    model = onnx.load(str(onnx_path))
    for inp in model.graph.input:            # pin the dynamic batch for shape inference
        dims = inp.type.tensor_type.shape.dim
        if dims and not dims[0].dim_value:
            dims[0].dim_value = batch
    model = shape_inference.infer_shapes(model)
    shapes = {}
    for vi in list(model.graph.value_info) + list(model.graph.input) + list(model.graph.output):
        shapes[vi.name] = [d.dim_value for d in vi.type.tensor_type.shape.dim]
    for init in model.graph.initializer:
        shapes[init.name] = list(init.dims)
    by_op: dict[str, int] = {}
    activations = 0
    for node in model.graph.node:
        macs = 0
        if node.op_type in ("Conv", "ConvTranspose"):
            out = shapes.get(node.output[0])
            wshape = shapes.get(node.input[1])
            if out and wshape:
                # Conv weight (C_out, C_in / group, kH, kW): each output element takes prod(w[1:]) MACs;
                # ConvTranspose weight (C_in, C_out / group, kH, kW): each input element scatters them.
                per = int(np.prod(wshape[1:]))
                macs = int(np.prod(out)) * per if node.op_type == "Conv" else \
                    int(np.prod(shapes.get(node.input[0], [0]))) * per
        elif node.op_type in ("Gemm", "MatMul"):
            a = shapes.get(node.input[0])
            out = shapes.get(node.output[0])
            if a and out:
                macs = int(np.prod(out)) * int(a[-1])
        if macs:
            by_op[node.op_type] = by_op.get(node.op_type, 0) + macs
            activations += int(np.prod(shapes.get(node.output[0]) or [0]))
    params = int(sum(int(np.prod(i.dims)) for i in model.graph.initializer))
    return {"macs": int(sum(by_op.values())), "by_op": by_op, "params": params, "activations": activations}


def ann_ops(macs: float, params: float = 0.0, activations: float = 0.0) -> HostOps:
    """A dense network pass: fp32 MACs, weights read once, activations written and read once."""
    return HostOps(mac_fp32=macs, sram_bytes=4 * params + 8 * activations)


# ---------------------------------------------------------------------------- Loihi activity
def synop_count(spikes: np.ndarray, kernel: int) -> np.ndarray:
    """Exact synaptic operations per target neuron for one step: the number of spiking sources
    inside each neuron's K x K receptive field, summed over input channels (zero padding)."""
    spikes = np.asarray(spikes)
    if spikes.ndim == 2:
        spikes = spikes[None]
    acc = np.zeros(spikes.shape[-2:], dtype=np.float32)
    ones = np.ones((kernel, kernel), np.float32)
    for ch in spikes:
        if ch.any():
            acc += cv2.filter2D(ch.astype(np.float32), cv2.CV_32F, ones, borderType=cv2.BORDER_CONSTANT)
    return np.rint(acc).astype(np.int64)


@dataclass
class LoihiActivity:
    """Counted activity of one layer (population) over the steps of one inference.

    Per step t: synops[t] (total), active[t] (updates with input, state or spike), spikes[t], and
    the per-core maxima of the time model, core_time_ns[t] = max_c(...) (see module doc).
    """

    n_neurons: int
    synops: list[int] = field(default_factory=list)
    active: list[int] = field(default_factory=list)
    spikes: list[int] = field(default_factory=list)
    core_time_ns: list[float] = field(default_factory=list)

    @property
    def steps(self) -> int:
        return len(self.synops)

    @property
    def n_cores(self) -> int:
        return int(math.ceil(self.n_neurons / c("loihi2_neurons_per_core")))

    def add_step(self, syn_per_neuron: np.ndarray, active: np.ndarray, spikes: np.ndarray) -> None:
        """Record one step from per-neuron maps (H, W): synops, active flags, output spikes."""
        per_core = int(c("loihi2_neurons_per_core"))
        syn = np.asarray(syn_per_neuron, np.int64).ravel()
        act = np.asarray(active, bool).ravel()
        n = syn.size
        n_cores = int(math.ceil(n / per_core))
        starts = np.arange(n_cores) * per_core
        syn_c = np.add.reduceat(syn, starts)
        act_c = np.add.reduceat(act.astype(np.int64), starts)
        size_c = np.minimum(starts + per_core, n) - starts
        t_c = ((size_c - act_c) * c("loihi_update_inactive_t") + act_c * c("loihi_update_active_t")
               + syn_c * c("loihi_synop_t"))
        self.synops.append(int(syn.sum()))
        self.active.append(int(act.sum()))
        self.spikes.append(int(np.count_nonzero(spikes)))
        self.core_time_ns.append(float(t_c.max()) if t_c.size else 0.0)

    def energy_j(self) -> float:
        syn, act, spk = sum(self.synops), sum(self.active), sum(self.spikes)
        inactive = self.n_neurons * self.steps - act
        pj = (syn * c("loihi_synop_e") + act * c("loihi_update_active_e") + inactive * c("loihi_update_inactive_e")
              + spk * c("loihi_spike_e"))
        return pj * 1e-12

    def t_ts_s(self) -> list[float]:
        """Modelled time of each step (s): slowest core plus the barrier."""
        return [(t + c("loihi_barrier_t")) * 1e-9 for t in self.core_time_ns]

    def latency_s(self) -> float:
        """L = sum_t T_ts[t] (= mean T_ts * B)."""
        return float(sum(self.t_ts_s()))

    def summary(self) -> dict:
        t = self.t_ts_s()
        return {"neurons": self.n_neurons, "cores": self.n_cores, "steps": self.steps,
                "synops": int(sum(self.synops)), "active_updates": int(sum(self.active)),
                "inactive_updates": int(self.n_neurons * self.steps - sum(self.active)),
                "spikes": int(sum(self.spikes)), "t_ts_mean_us": float(np.mean(t) * 1e6) if t else 0.0,
                "latency_ms": self.latency_s() * 1e3, "energy_mj": self.energy_j() * 1e3}


def constants_table() -> dict:
    return {k: dataclasses.asdict(v) for k, v in CONSTANTS.items()}


def loihi2_footprint(width: int, height: int, n_stages: int, kernel: int, channels: int = 2, pool: int = 1) -> dict:
    """Neurons, synapses, cores and chips the OFS cascade takes on Loihi 2 at a sensor size.

    One neuron per cell of the OFS grid (the sensor pooled over ``pool`` x ``pool`` blocks,
    ceil(W / pool) x ceil(H / pool); ToffeConfig.ofs_pool) and stage; synapses per stage = H W C K^2 (each neuron's fan-in, the
    conv stores only C K^2 shared weights); cores per stage = ceil(H W / 8192) at the densest
    placement (8192 neurons per core, so a lower bound: synapse and axon memory can need more);
    chips = ceil(cores / 128). ``max_pixels_one_chip`` is the OFS-grid area at which all
    stages would fit one chip at that density.
    """
    per_core, per_chip = int(c("loihi2_neurons_per_core")), int(c("loihi2_cores_per_chip"))
    gw, gh = -(-int(width) // int(pool)), -(-int(height) // int(pool))
    neurons = gw * gh
    cores = int(math.ceil(neurons / per_core))
    total = cores * int(n_stages)
    return {"sensor": [int(width), int(height)], "ofs_pool": int(pool), "ofs_grid": [gw, gh], "stages": int(n_stages),
            "per_stage": {"neurons": neurons, "synapses": neurons * int(channels) * int(kernel) ** 2,
                          "shared_weights": int(channels) * int(kernel) ** 2, "cores": cores},
            "neurons": neurons * int(n_stages), "cores": total, "chips": int(math.ceil(total / per_chip)),
            "fits_one_chip": total <= per_chip,
            "max_pixels_one_chip": (per_chip // int(n_stages)) * per_core,
            "note": f"{per_core} neurons per core (densest placement: cores are a lower bound), "
                    f"{per_chip} cores per chip (Intel Loihi 2 brief)"}
