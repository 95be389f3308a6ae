"""Speed and equivalence measurements, run from the repository's root as ``python -m benchmarks.<name>``: each
prints a table and writes ``benchmarks/results/<name>.json``."""
