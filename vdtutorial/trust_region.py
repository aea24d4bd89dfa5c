"""TRPO's step as numerical pieces that know nothing of environments: the gradient of a scalar as one vector, the
Fisher-vector product by double backward, conjugate gradient, and the backtracking line search that enforces the KL
bound (steps 3-6 of :mod:`vdtutorial.trpo`).

Chapter 06 builds each piece on its own and checks it against a brute-force computation (sections 1, 2 and 5) before
:class:`vdtutorial.trpo.TRPO` puts them together; they live apart from the algorithm so that each can be read, taught
and tested without a rollout. :func:`double_backward_fvp` is TRPO's default Fisher-vector product;
:mod:`vdtutorial.fast.fisher` computes the same product in a cheaper form for the paper's Gaussian policy.

Taught in chapters 06a and 06b.
"""

from __future__ import annotations

from typing import Callable, Protocol

import torch
from torch import nn
from torch.distributions import Distribution, kl_divergence


class FisherProduct(Protocol):
    """A Fisher-vector product as TRPO takes it (``TRPO(fvp=...)``): called once per update with the policy, the
    parameters that move, the observations, pi_old on them (detached), the damping and, when the caller has it, the
    policy's distribution with its autograd graph; returns ``v -> (F + damping * I) v``. :func:`double_backward_fvp`
    serves any policy with ``distribution(obs)``; :func:`vdtutorial.fast.fisher.gauss_newton_fvp` the same matrix,
    cheaper, for the paper's Gaussian policy."""

    def __call__(
        self,
        policy: nn.Module,
        params: list[nn.Parameter],
        obs,
        old: Distribution,
        damping: float,
        dist: Distribution | None = None,
    ) -> Callable[[torch.Tensor], torch.Tensor]: ...


def flat_grad(
    y: torch.Tensor, params: list[nn.Parameter], create_graph: bool = False, retain_graph: bool | None = None
) -> torch.Tensor:
    """Gradient of the scalar ``y`` with respect to ``params`` as one vector (zeros for parameters it does not use)."""
    grads = torch.autograd.grad(y, params, create_graph=create_graph, retain_graph=retain_graph, allow_unused=True)
    return torch.cat([(torch.zeros_like(p) if g is None else g).reshape(-1) for p, g in zip(params, grads)])


def mean_kl(old: Distribution, new: Distribution) -> torch.Tensor:
    """TRPO's constraint, the mean KL(pi_old || pi_new) over the batch's states (Schulman et al., 2015,
    eq. 12): per state the KL of the diagonal Gaussian is the sum over its independent action dimensions."""
    return kl_divergence(old, new).sum(-1).mean()


def fisher_vector_product(
    kl_grad: torch.Tensor, params: list[nn.Parameter], v: torch.Tensor, damping: float
) -> torch.Tensor:
    """(F + damping * I) v without building F, the Hessian of the mean KL(pi_old || pi_theta) at theta_old, which equals
    the policy's Fisher information matrix. ``kl_grad`` is the gradient of the mean KL, computed once with
    ``create_graph=True``; differentiating ``kl_grad . v`` once more gives F v (keeping the graph of ``kl_grad``, which
    conjugate gradient differentiates again for the next v)."""
    return flat_grad(kl_grad @ v, params, retain_graph=True) + damping * v


def double_backward_fvp(
    policy: nn.Module,
    params: list[nn.Parameter],
    obs,
    old: Distribution,
    damping: float,
    dist: Distribution | None = None,
) -> Callable[[torch.Tensor], torch.Tensor]:
    """TRPO's Fisher-vector product for any policy, the one chapter 06a builds: v -> (F + damping * I) v, F the
    Hessian of the mean KL(old || pi_theta) over ``obs`` at the current parameters (:func:`fisher_vector_product`).

    ``old`` is the policy's distribution on ``obs`` now, detached; ``dist`` the same with its autograd graph, when the
    caller has it (TRPO's forward pass at theta_old), else one more forward pass makes it. Every Fisher-vector product
    TRPO accepts (``TRPO(fvp=...)``) has this signature, e.g. :func:`vdtutorial.fast.fisher.gauss_newton_fvp`."""
    dist = dist if dist is not None else policy.distribution(obs)
    kl_grad = flat_grad(mean_kl(old, dist), params, create_graph=True)
    return lambda v: fisher_vector_product(kl_grad, params, v, damping)


def conjugate_gradient(
    Avp: Callable[[torch.Tensor], torch.Tensor], b: torch.Tensor, iters: int = 10, residual_tol: float = 1e-10
) -> torch.Tensor:
    """Approximately solve A x = b for a symmetric positive-definite A, given only v -> A v: from x = 0, each
    iteration moves along a search direction A-conjugate to all previous ones, until ``iters`` iterations or a squared
    residual below ``residual_tol`` (in exact arithmetic the answer is exact after dim(b) iterations)."""
    x = torch.zeros_like(b)
    r = b.clone()  # residual b - A x
    p = b.clone()  # search direction
    r_dot_r = r @ r
    for _ in range(iters):
        if r_dot_r < residual_tol:
            break
        Ap = Avp(p)
        alpha = r_dot_r / (p @ Ap)
        x += alpha * p
        r -= alpha * Ap
        new_r_dot_r = r @ r
        p = r + (new_r_dot_r / r_dot_r) * p
        r_dot_r = new_r_dot_r
    return x


@torch.no_grad()
def set_flat_params(params: list[nn.Parameter], flat: torch.Tensor) -> None:
    """Copy the vector ``flat`` into ``params`` (in place, in order)."""
    start = 0
    for p in params:
        p.copy_(flat[start : start + p.numel()].view_as(p))
        start += p.numel()


def line_search(
    params: list[nn.Parameter],
    full_step: torch.Tensor,
    surrogate_and_kl: Callable[[], tuple[torch.Tensor, torch.Tensor]],
    max_kl: float,
    backtrack_iters: int = 10,
    backtrack_coeff: float = 0.5,
    surrogate_old: float | None = None,
) -> tuple[float | None, float, float]:
    """Backtracking line search along ``full_step`` from the current parameters. ``surrogate_and_kl()`` evaluates the
    surrogate and the mean KL(old || current) at the current parameters (one policy forward for both). Tries the
    fractions 1, c, c^2, ... (c = ``backtrack_coeff``) of the full step and accepts the first one whose mean KL is at
    most ``max_kl`` and whose surrogate is larger than at the start. Returns (accepted fraction, surrogate improvement,
    mean KL), leaving the parameters at the accepted point; or (None, 0.0, 0.0) with the parameters restored when no
    step passes. ``surrogate_old``, the surrogate at the current parameters, saves one evaluation when the caller
    already has it."""
    with torch.no_grad():
        theta_old = torch.cat([p.reshape(-1) for p in params]).clone()
        if surrogate_old is None:
            surrogate_old = surrogate_and_kl()[0].item()
        for i in range(backtrack_iters):
            fraction = backtrack_coeff**i
            set_flat_params(params, theta_old + fraction * full_step)
            surrogate, kl = (x.item() for x in surrogate_and_kl())
            improvement = surrogate - surrogate_old
            if kl <= max_kl and improvement > 0:
                return fraction, improvement, kl
        set_flat_params(params, theta_old)
    return None, 0.0, 0.0
