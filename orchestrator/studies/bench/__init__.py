"""Benchmarks: scripts and ``copath bench`` subcommands that print figures of speed, scale and robustness."""
