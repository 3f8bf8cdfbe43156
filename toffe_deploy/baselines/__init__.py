"""Baselines measured beside TOFFE in the same harness (benchmarks/energy_latency.py)."""
