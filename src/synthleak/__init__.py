"""synthleak: measure what a visual-localization service leaks about a scene through camera poses.

Pipeline (one subpackage per stage): assets -> scene -> render -> localize -> attack -> evaluate.
"""

__version__ = "0.1.0"
