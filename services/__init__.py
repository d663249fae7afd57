"""vrsim's services, one subpackage per job: `sim` (the simulation and Python API), `outputs` (files a
run writes), `bus` (the Zenoh services) and `cli` (the `vrsim` command).

Imports point one way: cli -> bus/outputs/sim -> maps/vehicle/controller -> common.
"""
