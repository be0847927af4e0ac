"""Importing this package registers every scenario."""

from . import egg_vs_stone  # noqa: F401
