"""lava-dl netx HDF5 (``.net``) of each OFS stage: input layer + conv layer with a CUBA neuron.

netx reads ``layer/<i>/...`` groups (lava.lib.dl.netx.hdf5.Network): an input layer giving the
shape (stored C, H, W) and a conv layer with inChannels, outChannels, kernelSize, stride,
padding, dilation, groups, weight (O, I, kH, kW) and neuron/{type, iDecay, vDecay, vThMant,
refDelay, gradedSpike = False: binary spikes}. netx builds Lava's LIF with vth = vThMant,
du = iDecay - 1, dv = vDecay and flips the kernel for Lava's true convolution, so storing our
cross-correlation weights unchanged with iDecay = du + 1 = 4096 reproduces our integers exactly.

netx's stock neuron resets v to 0 after a spike. A reset "zero" bundle's files reproduce its
OFS exactly when loaded as ``Network(net_config=f, reset_interval=n_bins,
reset_offset=NETX_RESET_OFFSET)`` (the parity check netx_vs_fixed runs that, 0 differing spikes);
a "subtract" bundle's (paper eq. 1) cannot, which every file and the manifest say
(``reset_note``). One file per stage: the cascade's masking between stages is not a netx layer.
"""
from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np

from ..config import ToffeConfig
from ..fixed_point import LoihiOFSParams

RESET_NOTES = {
    "subtract": "netx's stock CUBA neuron (Lava LIF) resets to zero after a spike; this bundle's OFS resets by "
                "subtraction (paper eq. 1), so netx does NOT reproduce it (spike F1 in parity.json "
                "netx_vs_fixed). Use lava_procs with ofs_loihi.json for the faithful model.",
    "zero": "netx's stock CUBA neuron resets to zero, as this bundle's OFS does: loaded with "
            "Network(net_config=FILE, reset_interval=n_bins, reset_offset=1) and fed bin b of window i at "
            "Lava step i * n_bins + b + 1 (steps count from 1: a lava.proc.io RingBuffer source's column "
            "i * n_bins + b), each file reproduces its stage bit for bit.",
}
#: netx.hdf5.Network(reset_interval=n_bins, reset_offset=NETX_RESET_OFFSET) starts every window
#: from rest when bin b of window i enters at Lava step i * n_bins + b + 1 (run_netx_stage).
NETX_RESET_OFFSET = 1
NETX_OUTPUT_DELAY = 1


def write_stage_netx(path: str | os.PathLike, config: ToffeConfig, p: LoihiOFSParams, stage: int) -> Path:
    """Write one stage as a netx network file at ``path``."""
    import h5py

    (w, h), c = config.ofs_grid(), config.ofs_in_channels     # the OFS grid (sensor pooled by ofs_pool)
    k = p.kernel_size
    path = Path(path)
    buf = io.BytesIO()     # in memory: HDF5's own writes crash the interpreter on a full disk
    with h5py.File(buf, "w") as f:
        f.attrs["producer"] = "toffe-deploy export"
        f.attrs["stage"] = stage
        f.attrs["reset_note"] = RESET_NOTES[p.reset]
        f.attrs["reset_interval"] = int(config.n_bins)
        f.attrs["reset_offset"] = NETX_RESET_OFFSET
        sim = f.create_group("simulation")
        sim.create_dataset("Ts", data=1)
        sim.create_dataset("tSample", data=int(config.n_bins))
        layer = f.create_group("layer")
        inp = layer.create_group("0")
        inp.create_dataset("type", data=np.bytes_("input"))
        inp.create_dataset("shape", data=np.array([c, h, w]))
        conv = layer.create_group("1")
        conv.create_dataset("type", data=np.bytes_("conv"))
        conv.create_dataset("shape", data=np.array([1, h, w]))
        for name, val in (("inChannels", c), ("outChannels", 1), ("kernelSize", k), ("stride", 1),
                          ("padding", k // 2), ("dilation", 1), ("groups", 1)):
            conv.create_dataset(name, data=val)
        conv.create_dataset("weight", data=np.asarray(p.weight, dtype=np.float32))
        neuron = conv.create_group("neuron")
        neuron.create_dataset("type", data=np.bytes_("CUBA"))
        neuron.create_dataset("iDecay", data=int(p.du) + 1)
        neuron.create_dataset("vDecay", data=int(p.dv))
        neuron.create_dataset("vThMant", data=int(p.vth_mant))
        neuron.create_dataset("refDelay", data=1)
        neuron.create_dataset("gradedSpike", data=False)
    with open(path, "wb") as fh:
        fh.write(buf.getbuffer())
    return path


def write_ofs_netx(folder: str | os.PathLike, config: ToffeConfig, ofs) -> list[Path]:
    """netx/ofs_stage<k>.net for every stage; returns the written paths."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    return [write_stage_netx(folder / f"ofs_stage{k}.net", config, p, k) for k, p in enumerate(ofs, start=1)]


def resize_netx(src: str | os.PathLike, dst: str | os.PathLike, height: int, width: int) -> Path:
    """Copy a stage file with its layer shapes set to (height, width): the same integers and
    neuron on a crop, so that netx's simulator (about 1 s per step at 640x480) checks them fast."""
    import h5py

    buf = io.BytesIO()
    with h5py.File(src, "r") as fin, h5py.File(buf, "w") as fout:
        for key, val in fin.attrs.items():
            fout.attrs[key] = val
        for name in fin:
            fin.copy(fin[name], fout, name=name)
        for i in fout["layer"]:
            shape = fout[f"layer/{i}/shape"][()]
            del fout[f"layer/{i}/shape"]
            fout[f"layer/{i}"].create_dataset("shape", data=np.array([shape[0], int(height), int(width)]))
    dst = Path(dst)
    with open(dst, "wb") as fh:
        fh.write(buf.getbuffer())
    return dst


def netx_network_class():
    """lava.lib.dl.netx.hdf5.Network, imported without the notices lava-dl's import prints on
    every run ("No CUDA runtime is found", "Prophesee Dataset Toolbox could not be found"):
    they are about parts of lava-dl this project does not use, and they broke `export --quiet`."""
    import contextlib
    import io

    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        from lava.lib.dl.netx.hdf5 import Network
    return Network


def load_netx(path: str | os.PathLike):
    """lava.lib.dl.netx.hdf5.Network of a stage file (imports lava-dl, hence torch)."""
    return netx_network_class()(net_config=str(path))


def run_netx_stage(path: str | os.PathLike, windows, reset_offset: int = NETX_RESET_OFFSET,
                   output_delay: int = NETX_OUTPUT_DELAY) -> list[np.ndarray]:
    """Run one stage file through lava-dl's own ``netx.hdf5.Network`` (Loihi2SimCfg, fixed_pt),
    as a user of the bundle would, on consecutive windows (B, C, H, W); returns their spikes
    (B, H, W) bool.

    Bin b of window i enters at Lava step i * B + b + 1 (lava.proc.io RingBuffer source); netx
    zeroes the neurons where step mod B == reset_offset (reset_interval = B); the spikes of that
    bin leave ``output_delay`` steps later (the Conv synapse's delay) through a
    ``lava.proc.io.extractor.Extractor`` (through ports: Var.get() moves data element by
    element), its buffer one slot a step. The runtime is stopped in every case. Lava's I/O
    processes have no tagged models, so they are named explicitly.
    """
    from ..runtime.loihi import import_lava

    import_lava()
    Network = netx_network_class()
    from lava.magma.core.run_conditions import RunSteps
    from lava.magma.core.run_configs import Loihi2SimCfg
    from lava.proc.io.extractor import Extractor, PyLoihiExtractorModel
    from lava.proc.io.source import PySendModelFixed, RingBuffer as Source

    wins = [np.asarray(x) > 0 for x in windows]
    b = wins[0].shape[0]
    steps = len(wins) * b + output_delay
    data = np.zeros(wins[0].shape[1:][::-1] + (steps,), np.int32)       # (W, H, C, T)
    for i, x in enumerate(wins):
        data[..., i * b:(i + 1) * b] = x.transpose(3, 2, 1, 0)
    net = Network(net_config=str(path), reset_interval=b, reset_offset=reset_offset)
    src, sink = Source(data=data), Extractor(shape=net.out.shape, buffer_size=steps)
    src.s_out.connect(net.inp)
    net.out.connect(sink.in_port)
    cfg = Loihi2SimCfg(select_tag="fixed_pt", exception_proc_model_map={Source: PySendModelFixed,
                                                                         Extractor: PyLoihiExtractorModel})
    try:
        net.run(condition=RunSteps(num_steps=steps), run_cfg=cfg)
        out = np.stack([sink.receive() for _ in range(steps)], axis=-1)   # (W, H, 1, T)
    finally:
        net.stop()
    spikes = out[:, :, 0, output_delay:].transpose(2, 1, 0) != 0           # (T', H, W)
    return [spikes[i * b:(i + 1) * b] for i in range(len(wins))]
