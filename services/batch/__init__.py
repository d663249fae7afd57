"""Many runs at once on Dask: an embedded `LocalCluster` or an existing cluster by its scheduler's
address. The only room that imports `dask.distributed`; it runs plain functions of plain data (the
tasks of `services.sim.sweep`) and hands each result back as it finishes. It writes no files.
"""
