"""Evaluation in layers: `arms` (what a verdict judges, and how files spell it), `runner` (the
Evaluator: recorded, resumable episodes) and `verdicts` (is a ticket golden? the tests, Holm's
adjustment once, and the frozen result types)."""

from goldenticket.evaluation.arms import BASE, MIXTURE, ZERO, Arm, Kind
from goldenticket.evaluation.runner import Bar, Evaluator, Job
from goldenticket.evaluation.verdicts import (
    ALPHA,
    Judged,
    MultitaskVerdict,
    Verdict,
    VerdictRow,
    judge,
    judge_size,
    judged_arms,
    multitask_verdict,
    p_value_note,
    pooled,
    regressions,
    to_dicts,
)

__all__ = ["ALPHA", "BASE", "MIXTURE", "ZERO", "Arm", "Bar", "Evaluator", "Job", "Judged", "Kind",
           "MultitaskVerdict", "Verdict", "VerdictRow", "judge", "judge_size", "judged_arms",
           "multitask_verdict", "p_value_note", "pooled", "regressions", "to_dicts"]
