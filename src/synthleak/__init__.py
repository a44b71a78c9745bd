"""synthleak: measure what a visual-localization service leaks about a scene through camera poses.

Pipeline (one subpackage per stage): assets -> scene -> render -> localize -> attack -> evaluate.
"""

from synthleak.torch_env import pin_torch_env

__version__ = "0.1.0"

pin_torch_env()  # before anything can start torch: its kernels and MKL's mode are chosen once per process
