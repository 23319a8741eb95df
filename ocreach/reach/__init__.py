"""Reachability methods and their common result type."""
from ocreach.reach.base import Method, available_methods, method_class, reach
from ocreach.reach.result import ReachResult, load

__all__ = ["Method", "ReachResult", "available_methods", "load", "method_class", "reach"]
