"""Which pretrainings a study needs, from its params alone (``training.pretrain``; the training itself:
``metraw.segment.pretrain``).

With pretraining on, each CFA pattern among the parameter points gets one pretraining across the tolerance box
and every point fine-tunes its pattern's; a synthetic source may add ``extra_scenes`` generated scenes. The
workflow's rules (workflow/rules/common.smk) and dvc.yaml's generator ask here, so this module imports only the
study's point logic: Snakemake reads it each time it builds the DAG.
"""

from __future__ import annotations

from typing import Any

from metraw.study.points import NOMINAL, parameter_points, target_params

#: ``training.pretrain`` of params.yaml, where it leaves a key out (measured settings: docs/training.md).
#: ``batch_size`` None: the training profile's (the fine-tunings always keep the profile's). ``finetune_learning_rate``
#: None: the fine-tunings' peak learning rate is the training profile's.
PRETRAIN_DEFAULTS = {"enabled": False, "box": {}, "epochs": 20, "points_per_scene": 4, "finetune_epochs": 5,
                     "finetune_learning_rate": None, "extra_scenes": 0, "batches": "payload", "batch_size": None}
#: ``training.pretrain.batches``: "payload" = each batch one box parameter at neighbouring values
#: (``metraw.segment.pretrain.payload_keys``, ``metraw.segment.onthefly.payload_batches``); "mixed" = draws of any
#: payload in a batch.
BATCHES = ("payload", "mixed")


def pretrain_settings(params: dict[str, Any]) -> dict[str, Any]:
    """``training.pretrain`` of a params mapping with ``PRETRAIN_DEFAULTS`` filled in."""
    return {**PRETRAIN_DEFAULTS, **(params.get("training", {}).get("pretrain") or {})}


def fine_tuned_points(params: dict[str, Any]) -> list[str]:
    """The parameter points whose training fine-tunes a pretraining: with pretraining on, every point (each from the
    pretraining of its own CFA pattern, ``point_patterns``), else none. The workflow's rules and dvc.yaml ask here."""
    return list(parameter_points(params)) if pretrain_settings(params)["enabled"] else []


def point_patterns(params: dict[str, Any]) -> dict[str, str]:
    """Point name -> its CFA pattern, the pretraining it fine-tunes (``pretrained_patterns``)."""
    return {p: target_params(params, p)["cfa_pattern"] for p in parameter_points(params)}


def pretrained_patterns(params: dict[str, Any]) -> list[str]:
    """The CFA patterns pretrained (one pretraining each; the nominal's first): those of the points, with pretraining
    on; none without."""
    if not pretrain_settings(params)["enabled"]:
        return []
    patterns = point_patterns(params)
    return list(dict.fromkeys([patterns[NOMINAL], *patterns.values()]))


def draws_extra_scenes(params: dict[str, Any]) -> bool:
    """Whether the pretraining draws ``extra_scenes`` synthetic scenes (a synthetic source only: the generator at the
    next seed). The workflow's rules and dvc.yaml both ask here."""
    settings = pretrain_settings(params)
    return bool(settings["enabled"] and settings["extra_scenes"] > 0 and params["source"]["dataset"] == "synthetic")
