"""Command-line entry points of the runtime (a3d-run, a3d-eval)."""
