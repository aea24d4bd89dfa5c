"""Beyond the paper's recipe: the imitation methods it cites and a value baseline for TRPO.

Modules, one idea each: :mod:`~vdtutorial.beyond.imitation_rounds` (cloning in rounds of new demonstrations),
:mod:`~vdtutorial.beyond.dart` (noise injected into the expert, Laskey et al. 2017) and
:mod:`~vdtutorial.beyond.dagger` (the expert relabels the learner's own states, Ross et al. 2011), and
:mod:`~vdtutorial.beyond.value_baseline` (a value network for TRPO's baseline,
as sb3-contrib uses). They build on the core, and nothing in the core needs them.

Taught in chapter 09.
"""
