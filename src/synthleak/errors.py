"""synthleak's error classes: every error raised for bad input or a missing dependency is a
:class:`SynthleakError` whose message names the file and the field (the CLI prints it as one line and exits
non-zero). Subclasses keep the built-in base their callers catch (``ValueError``, ``KeyError``, ...)."""

from __future__ import annotations


class SynthleakError(Exception):
    """Base class of synthleak's errors; ``str(error)`` is a one-line message naming the file and the field."""

    def __str__(self) -> str:  # KeyError subclasses would otherwise print the repr of their message
        return str(self.args[0]) if len(self.args) == 1 else super().__str__()


class ConfigError(SynthleakError, ValueError):
    """A config file (a study config, an object library model) that cannot be used; the message names the file
    and the key."""


class StageError(SynthleakError, ValueError):
    """A USD stage (or stage folder) that is missing or cannot be read; the message names the file and, where
    known, the prim."""


class UnknownNameError(SynthleakError, KeyError):
    """A name (model id, shape parameter, part) that is not defined; the message lists the known ones."""


class MissingDependencyError(SynthleakError, ImportError):
    """An optional dependency is not installed; the message says how to install it."""


class ServiceUnreachableError(SynthleakError, ConnectionError):
    """No localization service answers at a URL (nothing listens, a wrong host, a timeout); the message names the
    URL."""
