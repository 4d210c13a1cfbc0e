"""The rerun view: one entity tree on a frame timeline, a default blueprint."""
