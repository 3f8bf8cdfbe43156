"""Cascade bridge: collects a stage's window, masks the next stage's input (eq. 3-4)."""
