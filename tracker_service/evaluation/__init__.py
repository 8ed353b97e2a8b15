"""The product's judge: run the local trackers on a recording with truth and measure the
tracks the way air-traffic surveillance is judged (EUROCONTROL ESASSP).

``pipeline`` runs the trackers, ``metrics`` associates tracks to true aircraft and
computes the metrics, ``command`` is ``tracker-service evaluate``, ``report`` (needs
matplotlib) writes the Markdown report with figures.
"""

from tracker_service.evaluation.command import Evaluation, add_arguments, evaluate, main, run
from tracker_service.evaluation.pipeline import EvaluationConfig, run_pipeline

__all__ = [
    "Evaluation",
    "EvaluationConfig",
    "add_arguments",
    "evaluate",
    "main",
    "run",
    "run_pipeline",
]
