"""Analyses of finished runs and recordings: figures of the logged channels."""
