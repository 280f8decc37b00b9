"""The edges: Hydra entry points (sysid-run, sysid-diagnose, sysid-report), results files, recordings."""
