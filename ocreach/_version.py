"""The package version (one place: read by ``ocreach.__version__`` and written into result metadata)."""
__version__ = "0.1.0"
