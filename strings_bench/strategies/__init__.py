"""Densification strategies (gsplat style): see base.py for the interface."""

from .base import Strategy, scaled_interval, scaled_step
from .default import DefaultStrategy

__all__ = ["Strategy", "DefaultStrategy", "scaled_step", "scaled_interval"]
