"""Importers of recorded traffic into Scenarios."""
