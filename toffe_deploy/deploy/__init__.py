"""The deploy bundle: what ``toffe-deploy export`` writes and ``toffe-deploy run`` reads.

``bundle`` (layout, manifest, sha256 verification, torch-free) is the only part the runtime
needs; the writers (netx HDF5, NIR, ONNX) and the parity checks import torch/Lava lazily.
"""
