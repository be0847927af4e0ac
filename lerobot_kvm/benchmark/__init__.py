"""Measurement pipelines: continual-learning sequences (and, later, the obsolescence benchmark)."""
