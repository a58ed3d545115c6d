"""The package version, in a module of its own so that the store and the CLI can record it without
importing the package root."""

__version__ = "0.1.0"
