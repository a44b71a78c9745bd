"""Rendering: photoreal RGB backends (``registry.get_renderer``), exact ray-cast ground truth
(``raycast``), camera paths (``trajectories``), the dataset layout of docs/DATASET.md (``dataset``) and the
resumable stage-to-dataset pipeline (``pipeline``)."""
