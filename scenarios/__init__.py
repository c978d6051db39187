"""Scenario files, their ground-truth worlds, routes and trials."""

from scenarios.scenario import Scenario, bundled_names, load_scenario, resolve_path
from scenarios.schema import ScenarioError, ScenarioSpec

__all__ = ["Scenario", "ScenarioError", "ScenarioSpec", "bundled_names", "load_scenario", "resolve_path"]
