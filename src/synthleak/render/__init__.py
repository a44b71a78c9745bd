"""Rendering: photoreal RGB backends (``registry.get_renderer``), exact ray-cast ground truth
(``raycast``), camera paths (``trajectories``), the writers of the dataset layout of
docs/DATASET.md (``dataset``; its reader is ``synthleak.core.dataset``) and the resumable stage-to-dataset
pipeline (``pipeline``)."""
