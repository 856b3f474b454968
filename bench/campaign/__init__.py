"""Fault-injection campaigns: a spec expands into seeded trials, run in parallel (local
processes or a Dask cluster), stored as they finish, resumable, summarised in one report."""
