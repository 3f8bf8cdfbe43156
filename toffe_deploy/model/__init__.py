"""PyTorch models of TOFFE (training side: needs the [lava] extra, which brings torch)."""
