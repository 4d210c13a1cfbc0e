"""Posed sequences: boxes in the world, the object map built over a recording, and labels drawn once
for a whole recording (docs/mapping.md)."""
