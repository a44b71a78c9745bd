"""Renderer-free bottom layer: shared types and the dataset contract (imported by every stage, imports none)."""
