"""The simulation: scenarios, world building, the control core, landing, metrics, the in-process run.

Pure and importable (no Zenoh, no command line, no output files): this is vrsim's Python API.
"""
