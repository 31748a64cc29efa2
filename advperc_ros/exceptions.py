"""Every exception advperc_ros raises on purpose, under one base class.

`AdvpercError` is what a caller catches to tell "this tool refused the input or the situation"
from a bug. The expected failures (`advperc_ros.exits` maps them to one line and an exit code)
keep the standard base they always had (`ValueError` for bad input, `RuntimeError` for a state
the tool cannot work in), so code that caught those still does. The internal ones (a rollout
budget spent, a plan call overrunning its time) are control flow that never leaves the package.

This module imports nothing of the package, so every layer (core included) may import it.
"""

from pathlib import Path


class AdvpercError(Exception):
    """Base of every exception this package raises on purpose."""


# ----- bad input: exit code 2 (advperc_ros.exits.INPUT_ERRORS) -----

class ParamsError(AdvpercError, ValueError):
    """A params file that cannot be used; the message names the file and the parameter."""


class BagError(AdvpercError, ValueError):
    """A bag that cannot be used; the message names the file and the topic or field."""


class ScenarioError(AdvpercError, ValueError):
    """Ground truth that cannot be used; the message names the offending field."""


class PluginError(AdvpercError, ValueError):
    """A plug-in (planner, search method, interface profile, backend) that cannot be found, imported or
    built, or is not what its registry takes; the message names it (`advperc_ros.core.plugins`)."""


class PEMError(AdvpercError, ValueError):
    """A model file that cannot be used; the message names the file and the field."""


class MessageError(AdvpercError, ValueError):
    """A message that does not follow the topic contract; the text names the field."""


class OutputError(AdvpercError, ValueError):
    """An output place a run cannot write or may not take (a path that cannot become the folder or file
    asked for, one that exists already, one another run holds); the message names the path. Found
    before any work, so no long run is lost to it."""


class ResultsError(AdvpercError, ValueError):
    """A results folder another command reads (replay, the report's pictures, a replay campaign) whose
    report.json or errors.npz is missing or not what an attack writes; the message names the file."""


class OutOfSpace(AdvpercError, OSError):
    """The output's disk is too full for the run: refused before the work when the estimate does not
    fit, or stopped with the checkpoint kept when the disk fills during it; the text says how much
    and how to go on."""


# ----- nothing to attack, or no way to attack it -----

class GroundTruthFails(AdvpercError, RuntimeError):
    """The stack already breaks the rule with perfect perception: there is nothing to attack."""


class ScenarioRejected(AdvpercError, RuntimeError):
    """Recorded traffic that no ego motion escapes: attacking it would say nothing about perception."""


# ----- the graph backend and its transport -----

class GraphError(AdvpercError, RuntimeError):
    """The graph could not be started or made ready; the text says which node and why."""


class NodeGone(GraphError):
    """A node the graph needs went for good mid-search (its process exited, or it left the ROS graph):
    every rollout after it would wait out its timeout and find nothing, so the search stops at once,
    its checkpoint kept for a resume once the node runs again."""


class InconclusiveSearch(AdvpercError, RuntimeError):
    """Most rollouts of a search found nothing out (a node dead or silent, another graph on the
    domain, a planner raising): no collision found would be a claim the search cannot make."""


class RolloutFault(AdvpercError):
    """A rollout the graph failed to finish (not the planner's verdict); `gone` says how a node it needs
    went for good, where the player saw it (no publisher of the plans left), else ""."""

    def __init__(self, text: str, gone: str = "") -> None:
        super().__init__(text)
        self.gone = gone


class DdsError(AdvpercError, RuntimeError):
    """A transport that cannot be set up as asked; the text says what and why."""


class MessageTypeMissing(AdvpercError, RuntimeError):
    """A message type this ROS 2 installation has no Python package for (rclpy needs one to make an
    endpoint); a node leaves out the optional topics of that type and says so."""


# ----- the user stopped it -----

class Interrupted(AdvpercError):
    """Ctrl-C (or SIGTERM) during an attack: the text says how to finish it (its checkpoint is kept);
    `output` is the results folder it was writing, so each way in (CLI, ROS node) can say it its way."""

    def __init__(self, text: str, output: Path | None = None) -> None:
        super().__init__(text)
        self.output = output


# ----- control flow inside the package -----

class BudgetSpent(AdvpercError, RuntimeError):
    """A rollout was asked for beyond the search's rollout budget: the search ends there."""


class PlanTimeout(AdvpercError):
    """A plan call overran `RolloutConfig.plan_timeout` (raised inside it by the alarm)."""


class PlanError(AdvpercError, ValueError):
    """A plan the ego cannot follow; the rollout that received it is inconclusive."""


class RequirementSearchFailed(AdvpercError, RuntimeError):
    """A search of `advperc requirements` failed as an attack can (its ground truth breaks the rule, a bag it
    cannot read): its results folder and line, and the exit code the attack would have ended with, which the
    command ends with too."""

    def __init__(self, line: str, exit_code: int | None) -> None:
        super().__init__(line)
        self.exit_code = exit_code
