"""The package's version: one definition, read by the package, its build and its files."""

__version__ = "0.1.0"
