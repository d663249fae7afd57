"""vrsim services: scenarios, the run loop, metrics, reports, the CLI and the Zenoh services.

This package composes `maps`, `vehicle` and `controller`; they never import it.
"""
