"""The generated demo library (DTC layout with planted traps) and the demo pool used by benchmarks."""
