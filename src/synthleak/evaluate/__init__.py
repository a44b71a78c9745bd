"""Scoring against exact ground truth: metrics, results tables, the defense sweep and figures.

Modules: :mod:`.metrics` (symmetry-aware rotation error, centre error, exact 3D IoU, success rates),
:mod:`.score` (one results row's placement fields), :mod:`.tables` (presence P/R tables, placement summary,
results files), :mod:`.defense_sweep` (Sec. 6 trade-off), :mod:`.plots`.
"""
