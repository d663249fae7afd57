"""The `vrsim` command: the entry point (`services.cli.main`) and one module per subcommand.

Thin: each command parses its arguments, calls `services.sim`, `services.outputs` or `services.bus`,
and lets `main` map errors to exit codes. Nothing outside this package imports it.
"""
