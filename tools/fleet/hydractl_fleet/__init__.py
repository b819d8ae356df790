"""The fleet: every machine's recordings diagnosed on Ray, each machine's
model followed over its life (see README.md)."""

__version__ = "0.1.0"
