"""The Zenoh services (one module each: map, vehicle, controller, monitor, scenario), their message
schemas and the Zenoh helpers they share. No service imports another service.

Keep imports here light: `vrsim --help` imports the command modules, which import this package.
"""
