"""The package's version: one place, read by the package, the program writers and the build."""

__version__ = "0.1.0"
