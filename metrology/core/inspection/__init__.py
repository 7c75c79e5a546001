"""Inspection of measured points against a nominal model."""
