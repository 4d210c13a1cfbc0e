"""Readers of public data (NYUv2 release, MCG candidates) and the RoI database."""
