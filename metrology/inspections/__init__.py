"""Inspection of measurements against nominal models: stored nominal meshes, inspection jobs, plans."""
