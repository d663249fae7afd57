"""vrsim's services, one subpackage per job: `sim` (the simulation and Python API), `outputs` (files a
run writes), `bus` (the Zenoh services), `batch` (many runs on Dask) and `cli` (the `vrsim` command).

Imports point one way: cli -> bus/batch/outputs/sim -> maps/vehicle/controller -> common.
"""
