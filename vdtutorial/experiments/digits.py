"""Sparse VD validated on a real data set: scikit-learn's 8 x 8 handwritten digits, a 64-300-100-10 MLP
(the LeNet-300-100 shape of Molchanov et al.) trained once with plain layers and once with sparse VD
(``python -m vdtutorial digits``). It checks the layers of :mod:`vdtutorial.vd` where the answer is known:
almost the same accuracy with most weights pruned.

Taught in chapter 04 and appendix A3: chapter 04 trains :func:`digits_mlp` and reads its sparsity, appendix A3
runs :func:`digits_validation`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from vdtutorial.analysis.sparsity import sparsity_report, SparsityReport
from vdtutorial.settings import budget
from vdtutorial.vd import make_linear, model_kl


@dataclass
class DigitsResult:
    """Test accuracies of the plain and the sparse-VD MLP, the VD model's sparsity, and the wall time."""

    dense_accuracy: float
    vd_accuracy: float
    fraction_pruned: float
    report: SparsityReport
    seconds: float


def digits_mlp(variational: bool, hidden: tuple[int, ...] = (300, 100)) -> nn.Sequential:
    """64-300-100-10 ReLU MLP (the LeNet-300-100 shape of Molchanov et al., on 8 x 8 images)."""
    sizes, layers = (64, *hidden, 10), []
    for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:])):
        layers.append(make_linear(a, b, variational))
        if i < len(sizes) - 2:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


def _train_classifier(
    model: nn.Module,
    x: torch.Tensor,
    y: torch.Tensor,
    epochs: int,
    batch_size: int,
    lr: float,
    warmup: float,
    generator: torch.Generator,
) -> None:
    """Adam on the per-example negative ELBO: cross-entropy + beta * KL / N (eqs. 1-3), beta rising
    linearly from 0 to 1 over the first ``warmup`` fraction of the steps. For a plain model KL = 0."""
    n = len(x)
    optimiser = torch.optim.Adam(model.parameters(), lr=lr)
    steps = epochs * math.ceil(n / batch_size)
    step = 0
    model.train()
    for _ in range(epochs):
        for idx in torch.randperm(n, generator=generator).split(batch_size):
            beta = min(1.0, step / (warmup * steps)) if warmup > 0 else 1.0
            loss = F.cross_entropy(model(x[idx]), y[idx]) + beta * model_kl(model) / n
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            step += 1


@torch.no_grad()
def _accuracy(model: nn.Module, x: torch.Tensor, y: torch.Tensor) -> float:
    model.eval()
    return (model(x).argmax(1) == y).float().mean().item()


def digits_validation(
    seed: int = 0, epochs: int | None = None, batch_size: int = 100, lr: float = 1e-3, warmup: float = 0.3
) -> DigitsResult:
    """Train the same MLP with plain and with sparse-VD layers on ``sklearn.datasets.load_digits``.

    Data: 1797 images of 8 x 8 pixels (intensities 0..16, scaled to [0, 1]), a stratified 80/20 split
    fixed by ``seed``. Both models get the same initialisation seed, data order and optimiser.
    ``epochs``: passes over the 1437 training images (default from :func:`~vdtutorial.settings.budget`);
    ``batch_size``: M of eq. 3; ``lr``: Adam's step size (it also bounds how fast log sigma^2 can grow,
    hence how fast weights get pruned); ``warmup``: fraction of training over which beta goes 0 -> 1.
    The VD accuracy is that of the deterministic eval-mode network with log alpha > 3 weights removed.

    What the defaults give on seeds 0-2 is in docs/results.md ("Sparse variational dropout and the policy").
    """
    epochs = epochs if epochs is not None else budget(200, 30)
    threads = torch.get_num_threads()
    # Matrices this small run several times faster on one thread than on two shared cores.
    torch.set_num_threads(1)
    try:
        return _digits_run(seed, epochs, batch_size, lr, warmup)
    finally:
        torch.set_num_threads(threads)


def _digits_run(seed: int, epochs: int, batch_size: int, lr: float, warmup: float) -> DigitsResult:
    from sklearn.datasets import load_digits
    from sklearn.model_selection import train_test_split

    start = time.perf_counter()
    data = load_digits()
    x_train, x_test, y_train, y_test = train_test_split(
        data.data / 16.0, data.target, test_size=0.2, stratify=data.target, random_state=seed
    )
    x_train, x_test = (torch.as_tensor(a, dtype=torch.float32) for a in (x_train, x_test))
    y_train, y_test = (torch.as_tensor(a, dtype=torch.long) for a in (y_train, y_test))
    models = {}
    for variational in (False, True):
        torch.manual_seed(seed)
        models[variational] = digits_mlp(variational)
        _train_classifier(
            models[variational], x_train, y_train, epochs, batch_size, lr, warmup, torch.Generator().manual_seed(seed)
        )
    report = sparsity_report(models[True])
    return DigitsResult(
        _accuracy(models[False], x_test, y_test),
        _accuracy(models[True], x_test, y_test),
        report.weight_fraction,
        report,
        time.perf_counter() - start,
    )
