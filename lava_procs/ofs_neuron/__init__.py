"""OFS neuron: fused 2->1 conv + LIF with the paper's reset by subtraction (eq. 1-2)."""
