"""Truth generators used by the benchmarks and tests (not installed)."""
