"""Energy and latency measurement: counters (readers), the idle-subtracted dynamic energy
(measure), and modelled figures from counted operations (cost_model)."""
