"""Reading and exploiting the sparsity sparse VD produces, beside the library: :mod:`~vdtutorial.analysis.sparsity`
(pruned weights and neurons, from the network's wiring; the paper's Table I counts) and
:mod:`~vdtutorial.analysis.compact` (the pruned network as a smaller plain one).

Taught in chapter 04.
"""
