"""The binary dropout rate matched to a sparse VD network: the rate of the ablation that keeps VD's multiplicative noise
without its learned per-weight variances (:class:`vdtutorial.methods.BinaryDropout`).

Why alpha / (1 + alpha)
    VD's weight w = theta (1 + sqrt(alpha) eps) carries multiplicative Gaussian noise of variance alpha; binary dropout
    at rate p, rescaled by 1 / (1 - p), carries multiplicative noise of mean 1 and variance p / (1 - p). The two have
    the same mean and variance when alpha = p / (1 - p), i.e. p = alpha / (1 + alpha) = sigmoid(log alpha)
    (Kingma, Salimans & Welling 2015, "Variational Dropout and the Local Reparameterization Trick"). One rate for the
    whole network is the mean of that p over the weights VD keeps (log alpha <= 3): the pruned ones are not part of
    the network RL starts from, and with p > 0.95 each they would swamp the mean.

Not taught in a chapter: it serves the ablations of VD planned in docs/plan-ablations-and-image-fig5.md.
"""

from __future__ import annotations

import torch
from torch import nn

from vdtutorial.vd import THRESHOLD, svdo_layers


@torch.no_grad()
def kept_dropout_rates(mu: nn.Module, threshold: float = THRESHOLD) -> torch.Tensor:
    """alpha / (1 + alpha) of every weight of ``mu``'s sparse-VD layers that is kept (log alpha <= ``threshold``)."""
    layers = svdo_layers(mu)
    if not layers:
        raise ValueError("a matched dropout rate needs a sparse-VD network (a VD checkpoint's mu)")
    return torch.cat([torch.sigmoid(layer.log_alpha[layer.keep_mask(threshold)]) for layer in layers])


def matched_dropout_rate(mu: nn.Module, threshold: float = THRESHOLD) -> float:
    """The mean over the kept weights of ``mu`` of alpha / (1 + alpha) (module docstring, "Why alpha / (1 + alpha)")."""
    return kept_dropout_rates(mu, threshold).mean().item()
