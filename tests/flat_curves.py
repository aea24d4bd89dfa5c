"""What the tests of the claims' records share (tests/test_looks.py, test_batches.py, test_ablation_claims.py): rows of
flat learning curves, whose final level and area are known without running anything.

Imported as ``from flat_curves import flat_rows``: pytest puts tests/, which has no ``__init__.py``, on ``sys.path``."""


def flat_rows(label: str, method: str, finals: dict[int, float]) -> list[dict]:
    """Flat learning curves of 10 iterations, one per seed: seed k's successes are ``finals[k]`` throughout, out of
    ``40 + k`` episodes (so that a rate differs from a count)."""
    return [
        {
            "label": label,
            "method": method,
            "seed": seed,
            "iteration": i,
            "env_steps": (i + 1) * 200,
            "successes": level,
            "episodes": 40 + seed,
        }
        for seed, level in finals.items()
        for i in range(10)
    ]
