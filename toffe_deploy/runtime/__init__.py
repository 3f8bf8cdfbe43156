"""Running a deploy bundle on a stream of events: OFS cascade backends (cpu compiled fixed point,
Lava simulator / Loihi 2), OFPD in onnxruntime, and the pipeline that joins them.

Heavy or optional dependencies (Lava, onnxruntime) are imported where used, never here.
"""
