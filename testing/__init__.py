"""Case generators and helpers that tests and benchmarks share (not shipped in the wheel)."""
