"""Knowledge distillation: a student trained on the averaged class probabilities of its teachers.

Hinton, Vinyals and Dean, "Distilling the Knowledge in a Neural Network" (2015). With the student's scores ``z``,
the true classes ``y``, ``K`` teachers' scores ``z_k``, the temperature ``T`` and the weight ``w`` (the recipe's
``distill_temperature`` and ``distill_weight``), each batch's loss is

.. math::

    p = \\frac{1}{K} \\sum_k \\operatorname{softmax}(z_k / T), \\qquad
    L = (1 - w)\\,\\mathrm{CE}(z, y) + w\\,T^2\\,\\mathrm{KL}\\bigl(p \\,\\|\\, \\operatorname{softmax}(z / T)\\bigr)

(``T**2`` keeps the soft term's gradient on the scale of the hard one's as ``T`` grows; the recipe's
``label_smoothing`` applies to the hard term only). The teachers' probabilities ``p`` are computed once per cell, in
eval mode, for every recording the student trains on, and travel with the split (``TensorSplit.soft``), so the
training loop's batches index them as they index ``x`` and ``y``.

**Which teachers.** A cell's teachers are cells of its own configuration with distillation off
(:func:`teacher_config`: the same model, revision, constructor keywords, recipe, dataset, fold and evaluation), one
per seed of its ``teacher_seeds``. Their weights come from the bench folder the ``teachers`` setting names, which
the harness checks against the teachers' records before a student runs. So a teacher was trained on exactly the
recordings its student trains on (train for a ``validation`` or ``tuning`` student, train + val for a ``final``
one), and nothing a teacher learnt comes from a split its student may not see.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import replace

import torch
import torch.nn.functional as F

from ..errors import ConfigError
from ..recipe import Recipe
from .build import build_model
from .config import CellConfig
from .evaluate import predict_scores
from .tensors import TensorSplit

__all__ = ["teacher_config", "load_teachers", "teacher_probabilities", "distillation_loss"]


def teacher_config(config: CellConfig) -> CellConfig:
    """The configuration of ``config``'s teachers: the same cell with distillation off (its hash names the teachers'
    cells)."""
    recipe = replace(config.recipe, distill_weight=0.0, distill_temperature=1.0)
    return replace(config, recipe=recipe, teacher_seeds=())


def load_teachers(config: CellConfig, spec: object, paths: Sequence[str | os.PathLike]) -> list[torch.nn.Module]:
    """The teacher models of ``config``, built for ``spec`` at the cell's revision, with the weights of ``paths``
    (safetensors files, one per teacher seed, in ``teacher_seeds`` order) loaded strictly.

    Raises:
        ConfigError: the paths do not match the cell's teacher seeds, or a file does not fit the model.
    """
    from safetensors.torch import load_file

    if len(paths) != len(config.teacher_seeds):
        raise ConfigError(f"{config.model} on {config.dataset}: {len(config.teacher_seeds)} teacher seed(s) "
                          f"{list(config.teacher_seeds)}, but {len(paths)} teacher weight file(s) given")
    models = []
    for path in paths:
        model = build_model(config.model, spec, config.hparams, 0, config.model_revision)
        try:
            model.load_state_dict(load_file(os.fspath(path)), strict=True)
        except (RuntimeError, OSError) as exc:  # a missing/unexpected key or a shape: the file is not this model's
            why = " ".join(str(exc).split())[:300]
            raise ConfigError(f"teacher weights {path}: do not fit {config.model}: {why}") from None
        models.append(model)
    return models


def teacher_probabilities(teachers: Sequence[torch.nn.Module], split: TensorSplit, temperature: float,
                          batch_size: int = 256, device: torch.device | None = None) -> torch.Tensor:
    """The teachers' mean class probabilities at ``temperature`` on every sample of ``split``: ``[S, K]``, float32,
    on the CPU, each row summing to 1 (the average is taken in float64)."""
    total = torch.zeros(len(split), split.spec.num_classes, dtype=torch.float64)
    if len(split) == 0:
        return total.float()
    g = split.g if split.g.shape[-1] > 0 else None
    for teacher in teachers:
        scores = predict_scores(teacher.to(device or "cpu"), split.x, g, batch_size, device)  # (S, K)
        total += torch.softmax(scores.double() / temperature, dim=-1)
    return (total / len(teachers)).float()


def distillation_loss(scores: torch.Tensor, y: torch.Tensor, soft: torch.Tensor, recipe: Recipe) -> torch.Tensor:
    """The recipe's distillation loss of a batch: scores ``[B, K]``, classes ``[B]``, teacher probabilities ``[B, K]``
    (the module docstring's ``L``; ``F.kl_div`` takes the student's log-probabilities and the teachers'
    probabilities, and ``batchmean`` is the per-sample KL divergence averaged over the batch)."""
    w, t = recipe.distill_weight, recipe.distill_temperature
    hard = F.cross_entropy(scores, y, label_smoothing=recipe.label_smoothing)
    soft_term = F.kl_div(F.log_softmax(scores / t, dim=-1), soft, reduction="batchmean")
    return (1.0 - w) * hard + w * t * t * soft_term
