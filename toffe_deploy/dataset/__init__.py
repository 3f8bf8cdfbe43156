"""The synthetic high-speed data set (the paper's "TOFFE Dataset", recreated as a generator).

appearance (randomized ranges, held-out region), shapes (anti-aliased SDFs), trajectories
(cylindrical, one lap time), dvs (log-intensity emulator), synth (rendering + ground truth),
splits (train/test/multi/appearance/pairs protocol), build (files + index.json), groundtruth
(per-window truth), show (PNG, Fig. 5b). The camera model is toffe_deploy.camera.
Modules are imported on use; importing this package is cheap.
"""
