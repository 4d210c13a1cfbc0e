"""Frame folders, fake models and configs shared by several test modules."""
