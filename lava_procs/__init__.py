"""TOFFE's Lava Processes: the OFS neuron, the event-bin source and the cascade bridge.

The OFS neuron here resets by subtraction (reset "subtract" bundles). Reset "zero" bundles use
no neuron of ours: each stage is Lava's stock ``lava.proc.conv.Conv`` + ``lava.proc.lif.LIFReset``
(what Loihi 2's NeuroCores run), between this package's source and bridges (``stock=True``),
which stay on the host (toffe_deploy.runtime.loihi).

Each Process lives in ``<name>/process.py`` (ports and Vars only) with its process models in
``<name>/models.py`` (tags ``fixed_pt`` and ``floating_pt``). Lava discovers process models by
executing every module in a Process's directory, so every module here is side-effect free and
cheap to import, and models import their Process by absolute name.

Spike planes cross ports bit-packed along x (``lava_procs.packing``): a 640x480 plane is 38 kB of
uint8 instead of 1.2 MB of int32, which is most of what makes a simulated step cheap.
"""
