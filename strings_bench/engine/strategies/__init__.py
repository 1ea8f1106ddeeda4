"""Densification strategies (gsplat style): see base.py for the interface."""

from strings_bench.engine.strategies.base import Strategy, StrategyContext, scaled_interval, scaled_step
from strings_bench.engine.strategies.default import DefaultStrategy

__all__ = ["Strategy", "StrategyContext", "DefaultStrategy", "scaled_step", "scaled_interval"]
