"""Rigid-transform helpers and the project's pose conventions."""
