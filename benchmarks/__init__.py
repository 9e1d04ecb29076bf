"""The project's benchmarks, run from the repo's root as modules (`python -m benchmarks.GROUP.NAME`):
accuracy/ (the estimators and the diagnosis, scored against the truth), daemon/ (the real daemon
on a pty: latency, CPU, faults, bad peers, footprint), speed/ (offline throughput), tools/
(this checkout beside another, profiling, one case inspected). `harness` holds what they share."""
