"""The paper's three experiments (Section V) in the simulated cell: scenarios, the runner that
wires world, tracker and control together, its log and its metrics."""

from cellsight.experiments.config import RunConfig
from cellsight.experiments.runner import ExperimentRun, run_experiment
from cellsight.experiments.scenario import DESCRIPTIONS, Scenario, scenario

__all__ = ["DESCRIPTIONS", "ExperimentRun", "RunConfig", "Scenario", "run_experiment", "scenario"]
