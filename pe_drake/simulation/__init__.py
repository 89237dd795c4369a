"""Simulated runs, the stage between identification and diagnosis (which does not import it): a
:class:`~pe_drake.multibody.robot_model.RobotModel` perturbed as a TRUTH.yaml says tracks a
trajectory in Drake and logs what a real robot would (:func:`simulate_run`); synthetic logs."""

from pe_drake.simulation.simulated_run import SimulatedRun, SimulateOptions, simulate_run
from pe_drake.simulation.truth import Truth, load_truth, make_truth

__all__ = ["SimulateOptions", "SimulatedRun", "Truth", "load_truth", "make_truth", "simulate_run"]
