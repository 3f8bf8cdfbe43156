"""lava-dl netx HDF5 (``.net``) of each OFS stage: input layer + conv layer with a CUBA neuron.

netx reads ``layer/<i>/...`` groups (lava.lib.dl.netx.hdf5.Network): an input layer giving the
shape (stored C, H, W) and a conv layer with inChannels, outChannels, kernelSize, stride,
padding, dilation, groups, weight (O, I, kH, kW) and neuron/{type, iDecay, vDecay, vThMant,
refDelay}. netx builds Lava's LIF with vth = vThMant, du = iDecay - 1, dv = vDecay and flips the
kernel for Lava's true convolution, so storing our cross-correlation weights unchanged with
iDecay = du + 1 = 4096 reproduces our integers exactly.

Caveat written into every file (and the manifest): netx's stock neuron resets v to 0 after a
spike, where the paper subtracts the threshold. The netx files are for interoperability; the
faithful deployment is lava_procs built from ofs_loihi.json. One file per stage, because the
cascade's masking between stages is not a netx layer.
"""
from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np

from ..config import ToffeConfig
from ..fixed_point import LoihiOFSParams

RESET_NOTE = ("netx's stock CUBA neuron (Lava LIF) resets to zero after a spike; TOFFE's OFS resets by "
              "subtraction (paper eq. 1). Use lava_procs with ofs_loihi.json for the faithful model.")


def write_stage_netx(path: str | os.PathLike, config: ToffeConfig, p: LoihiOFSParams, stage: int) -> Path:
    """Write one stage as a netx network file at ``path``."""
    import h5py

    c, h, w = config.ofs_in_channels, config.height, config.width
    k = p.kernel_size
    path = Path(path)
    buf = io.BytesIO()     # in memory: HDF5's own writes crash the interpreter on a full disk
    with h5py.File(buf, "w") as f:
        f.attrs["producer"] = "toffe-deploy export"
        f.attrs["stage"] = stage
        f.attrs["reset_note"] = RESET_NOTE
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


def load_netx(path: str | os.PathLike):
    """lava.lib.dl.netx.hdf5.Network of a stage file (imports lava-dl, hence torch)."""
    from lava.lib.dl.netx.hdf5 import Network

    return Network(net_config=str(path))
