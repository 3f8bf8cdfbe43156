"""The synthetic high-speed data set (the paper's "TOFFE Dataset", recreated as a generator).

camera (pinhole 640x480, 60 deg), shapes (anti-aliased SDFs), trajectories (cylindrical, one lap
time), dvs (log-intensity emulator), synth (rendering + ground truth), splits (train/test/multi
protocol), build (files + index.json), groundtruth (per-window truth), show (PNG, Fig. 5b).
Modules are imported on use; importing this package is cheap.
"""
