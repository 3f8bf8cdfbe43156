# The two set-up commands of the README. Both create .venv (Python 3.10) on first use.
.PHONY: setup demo test bench

setup:
	@bash scripts/setup.sh

# Main job end to end on the shipped defaults: export the shipped checkpoint, run it on the
# Lava simulator (Loihi 2 fixed point) with OFPD in onnxruntime, print and save the object flow.
demo: setup
	.venv/bin/toffe-deploy export ckpt/
	.venv/bin/toffe-deploy run --target loihi-sim --out runs/object_flow.jsonl
	@echo "object flow, one JSON line per window: the header and the first two windows of" \
	      "$$(wc -l < runs/object_flow.jsonl) lines in runs/object_flow.jsonl:"
	@head -n 3 runs/object_flow.jsonl

test: setup
	.venv/bin/python -m pytest -q tests

bench: setup
	.venv/bin/python benchmarks/energy_latency.py
