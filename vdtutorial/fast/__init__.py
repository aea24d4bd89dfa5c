"""The exact speed-ups, beside the core: the same numbers as the library's plain code, computed faster for
the paper's Gaussian policy. The experiments and the benchmarks pass them to the core explicitly.

:mod:`~vdtutorial.fast.fisher`: TRPO's Fisher-vector product in Gauss-Newton form, one tangent and one
backward pass over cached activations (``TRPO(fvp=gauss_newton_fvp)``) instead of autograd's double backward.
:mod:`~vdtutorial.fast.policy`: the Gaussian policy with its inputs prepared once per batch and mu's and
sigma's first convolutions run as one (``fast_policy(policy)``).

Taught in chapter 06b.
"""
