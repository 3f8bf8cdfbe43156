"""Counting rules: one function per rule, applied alike to every model's work (issue 14).

A model's ``Work`` says what one inference computes, independent of how it is coded: its
spiking layers (neurons, steps, synapses per neuron, the synaptic operations its input events
cause, the neuron updates that have input or state), its morphology runs, its mask
operations, and the rest (clustering, the OFPD network) that no rule changes. A rule turns
Work into operations (``HostOps``):

    event_driven(work): per input event its index; per synaptic op one int32 accumulate; per
                        neuron update with input or state a fixed-point LIF (1 mul + 3 adds);
                        morphology over the bounding box of the spikes (+ kernel reach);
                        masks over the window's events; a frame's pixels listed (for
                        clustering or grouping) from its events
    dense(work):        a zero-filled count frame per step and channel; per neuron, step and
                        synapse one fp32 MAC; per neuron and step a float LIF (1 MAC + 2 adds);
                        morphology and masks over whole frames; a frame's pixels listed by
                        scanning the whole frame

Energy of a rule's operations = compute (per-op energies) + memory (bytes moved x pJ/byte),
reported apart: ``energy_split``. Constants: cost_model.CONSTANTS (Horowitz, ISSCC 2014,
45 nm: 4.6 pJ fp32 MAC, 0.9 pJ fp32 add, 0.1 pJ int32 add, 3.1 pJ int32 mul, 0.03 pJ 8-bit op;
memory 10 pJ per 64-bit SRAM access = 1.25 pJ/B, and 1.3 nJ per 64-bit DRAM access = 162 pJ/B
for the all-DRAM bound). These per-op figures are LOWER BOUNDS on what a processor spends:
instruction fetch, control, caches beyond one access and static power are not in them.
``time_power`` is the other model: measured time x a stated power.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

from .cost_model import (HostOps, c, dense_conv_ops, dense_lif_ops, event_conv_ops, event_index_ops, fixed_lif_ops,
                         mask_ops, morphology_ops)

DRAM_PJ_PER_64B = 1300.0          # Horowitz ISSCC 2014: 1.3-2.6 nJ per 64-bit DRAM access (low end)
RULES = ("event", "dense")
RULE_LABELS = {
    "event": "event-driven rule (int32 accumulate per synop, fixed-point LIF on neurons with input or state, "
             "morphology on the spikes' box)",
    "dense": "dense rule (fp32 MAC per synapse of every neuron and step, float LIF on every neuron, "
             "full-frame morphology)",
}
ENERGY_NOTE = ("modelled, lower bound: Horowitz ISSCC 2014 45 nm per-op energies; memory 1.25 pJ/B "
               "(10 pJ per 64-bit SRAM access)")


@dataclass
class LayerWork:
    """One spiking layer over one inference: ``neurons`` x ``steps`` updates, each neuron with
    c_in * kernel^2 synapses; ``synops`` = sum over input events of their fan-out (event
    driven); ``active`` = neuron updates with input, non-zero state or a spike."""

    neurons: int
    steps: int
    c_in: int
    kernel: int
    synops: float
    active: float


@dataclass
class Work:
    """What one inference computes (see module doc). morph: (box pixels, kernel, passes) per
    morphology run, the box being the spikes' bounding box grown by the kernel's reach;
    mask_event / mask_dense: element-wise mask operations over the events / whole frames;
    scan_event / scan_dense: elements read to list a frame's pixels (DOTIE's separated pixels
    for its clustering, TOFFE's stage frames for its grouping): the pixels themselves / every
    pixel of the frames (an 8-bit compare and a byte read each);
    post: clustering and dense networks, priced the same by both rules."""

    frame_px: int
    steps: int
    channels: int
    input_events: int
    layers: list[LayerWork] = field(default_factory=list)
    morph: list[tuple[int, int, int]] = field(default_factory=list)
    mask_event: float = 0.0
    mask_dense: float = 0.0
    scan_event: float = 0.0
    scan_dense: float = 0.0
    post: HostOps = field(default_factory=HostOps)

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        return d


def event_driven(w: Work) -> HostOps:
    """The event-driven rule (module doc)."""
    ops = event_index_ops(w.input_events)
    for layer in w.layers:
        ops = ops + event_conv_ops(layer.synops) + fixed_lif_ops(layer.active)
    for box_px, k, passes in w.morph:
        ops = ops + morphology_ops(box_px, 1, k, passes)
    return ops + mask_ops(int(w.mask_event)) + HostOps(op_int8=w.scan_event, sram_bytes=w.scan_event) + w.post


def dense(w: Work) -> HostOps:
    """The dense rule (module doc)."""
    ops = event_index_ops(w.input_events) + HostOps(add_int32=w.input_events,
                                                    sram_bytes=2 * w.steps * w.channels * w.frame_px + 4 * w.input_events)
    for layer in w.layers:
        ops = ops + dense_conv_ops(layer.neurons, 1, layer.c_in, 1, layer.kernel, layer.steps) \
            + dense_lif_ops(layer.neurons, layer.steps)
    for _box, k, passes in w.morph:
        ops = ops + morphology_ops(w.frame_px, 1, k, passes)
    return ops + mask_ops(int(w.mask_dense)) + HostOps(op_int8=w.scan_dense, sram_bytes=w.scan_dense) + w.post


RULE_FUNCTIONS = {"event": event_driven, "dense": dense}


def host_part(w: Work) -> HostOps:
    """What stays on the host when the spiking layers run on Loihi 2, for every model alike: the
    event-driven rule without the layers (the events indexed for the chip, morphology over the
    spikes' box, masks over the events, the frames' pixels listed from themselves, and the
    rest: front end, clustering or grouping, OFPD). The event rule because the host is the
    deployed, event-driven code for both models (DOTIE's optimised level, TOFFE's runtime)."""
    return event_driven(dataclasses.replace(w, layers=[]))


def energy_split(ops: HostOps) -> dict:
    """{compute_uj, memory_uj (SRAM, 1.25 pJ/B), total_uj, memory_dram_uj (all-DRAM bound)}."""
    compute = dataclasses.replace(ops, sram_bytes=0.0).energy_j() * 1e6
    memory = ops.sram_bytes / 8.0 * c("sram_read_64b") * 1e-6
    return {"compute_uj": compute, "memory_uj": memory, "total_uj": compute + memory,
            "memory_dram_uj": ops.sram_bytes / 8.0 * DRAM_PJ_PER_64B * 1e-6, "bytes": ops.sram_bytes}


def mean_work_energy(works: list[Work]) -> dict:
    """Per rule: the mean over inferences of energy_split, and the mean ops."""
    return mean_rule_energy({rule: [fn(w) for w in works] for rule, fn in RULE_FUNCTIONS.items()})


def mean_rule_energy(rule_ops: dict) -> dict:
    """mean_work_energy for a model counted directly as HostOps per rule (rule -> [HostOps])."""
    out = {}
    for rule in RULE_FUNCTIONS:
        splits = [energy_split(o) for o in rule_ops.get(rule, [])]
        out[rule] = {k: sum(s[k] for s in splits) / max(len(splits), 1) for k in splits[0]} if splits else {}
        out[rule]["label"] = RULE_LABELS[rule]
    return out


def time_power(seconds: float, watts: float) -> float:
    """Energy (uJ) of ``seconds`` at a stated ``watts``: the time x power model."""
    return seconds * watts * 1e6
