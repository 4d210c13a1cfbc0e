"""Frame sources: where RGB-D frames come from (folders, data sets, bags, cameras)."""
