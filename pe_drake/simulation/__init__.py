"""Simulated runs (between identification and diagnosis): a "true" robot, a
:class:`~pe_drake.multibody.robot_model.RobotModel` perturbed as a TRUTH.yaml says, tracking a
trajectory in Drake and logging what a real robot would (:func:`simulate_run`), and the
synthetic logs of the tests and benchmarks.

Imports ``identification``, ``excitation``, ``multibody`` and the base layer; the diagnosis does
not import it.
"""

from pe_drake.simulation.simulated_run import SimulatedRun, simulate_run
from pe_drake.simulation.truth import Truth, load_truth

__all__ = ["SimulatedRun", "Truth", "load_truth", "simulate_run"]
