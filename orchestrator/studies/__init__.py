"""Studies over many runs: sweeps, envelopes, benchmarks."""
