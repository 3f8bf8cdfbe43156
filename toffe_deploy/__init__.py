"""toffe-deploy: deploy TOFFE object flow on Loihi 2 (Lava) plus an edge GPU (onnxruntime).

The base package (events, binning, the fixed-point OFS reference, the bundle reader and the
cpu/cuda runtime) imports neither torch nor Lava, so a Jetson can install just that part.
"""
__version__ = "0.1.0"
