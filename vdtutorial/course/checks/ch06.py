"""Trusted checks of chapter 06's exercises: in 06a REINFORCE (6.1), the surrogate (6.2), conjugate gradient (6.3),
the Fisher-vector product (6.4) and GAE (6.5); in 06b the linear baseline (6.6), the line search (6.7) and one
whole TRPO update (6.8).

The grader draws the inputs: batches of the one-step task of 06a's section 0, symmetric positive-definite
matrices, reward sequences with episode ends, baseline regressions, toy trust-region problems (a surrogate and a
KL in closed form) and small Gaussian policies, sent as their parameters' arrays. The kernel returns what the
student's functions give on them (for 6.7 and 6.8 also where they left the parameters), and the grader recomputes
each answer: by autograd of log pi (6.1, 6.2), with :func:`~vdtutorial.trust_region.conjugate_gradient`,
:func:`~vdtutorial.trust_region.double_backward_fvp`, :func:`vdtutorial.trpo.gae`,
:class:`vdtutorial.baselines.LinearFeatureBaseline`, :func:`~vdtutorial.trust_region.line_search` and
:meth:`vdtutorial.trpo.TRPO.update`. The old hidden tests' Pendulum batches (6.8) became random batches for a
small policy: the update never looks at where its batch came from, and these cost milliseconds. An update that
lands elsewhere than the library's is also compared with two slips whose numbers say little by themselves, a step
downhill (the surrogate's sign) and the step solved without damping, so that the failure names the slip.

Not taught in a chapter: part of the teacher's grading (vdtutorial/course/checks/__init__.py).
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
import math

import gymnasium as gym
import numpy as np
import torch
from torch.distributions import Normal

from vdtutorial.baselines import LinearFeatureBaseline
from vdtutorial.course.checks import Check, Failures
from vdtutorial.policy import GaussianPolicy, make_policy
from vdtutorial.rollout import make_vec_env
from vdtutorial.trpo import STEP_STATS, TRPO, Batch, TRPOConfig, gae
from vdtutorial.trust_region import conjugate_gradient, double_backward_fvp, line_search

#: Conjugate-gradient iterations each system is solved with: one, a few, and more than the systems of 2 and 5
#: unknowns need to converge (CG must then stop, or at least stay, at the solution).
CG_ITERS = (1, 2, 3, 8)


def _cases(inputs: dict) -> list[str]:
    return sorted((key for key in inputs if key.startswith("case")), key=lambda key: int(key[4:]))


def _log_density(theta: torch.Tensor, case: dict) -> torch.Tensor:
    """log N(a | w . s, sigma^2) per sample, theta = (w, log sigma): the task of 06a's section 0, in float64."""
    states, actions = torch.as_tensor(case["states"]), torch.as_tensor(case["actions"])
    return Normal(states @ theta[:-1], theta[-1].exp()).log_prob(actions)


def _bandit_case(rng, theta_old, n):
    """A batch that N(w_old . s, sigma_old^2) drew on n states of N(0, I_3), with advantages of either sign."""
    states = rng.standard_normal((n, 3))
    actions = states @ theta_old[:3] + math.exp(theta_old[3]) * rng.standard_normal(n)
    return {"states": states, "actions": actions, "advantages": rng.normal(-0.5, 2.0, n)}


def _theta(rng):
    return np.append(rng.normal(0.0, 1.0, 3), rng.uniform(-1.5, 0.5))


def reinforce_inputs(rng: np.random.Generator) -> dict:
    """Three batches of 40 samples at random parameters (w, log sigma)."""
    cases = {}
    for k in range(3):
        theta = _theta(rng)
        cases[f"case{k}"] = {"w": theta[:3], "log_std": theta[3], **_bandit_case(rng, theta, 40)}
    return cases


def reinforce_probe(namespace: dict, inputs: dict) -> dict:
    return {
        key: namespace["reinforce_gradient"](
            np.array(case["w"]), float(case["log_std"]), case["states"], case["actions"], case["advantages"]
        )
        for key, case in inputs.items()
    }


def reinforce_verdict(inputs: dict, outputs: dict) -> list[str]:
    failures = Failures()
    for key in _cases(inputs):
        case = inputs[key]
        theta = torch.tensor(np.append(case["w"], case["log_std"]), requires_grad=True)
        (_log_density(theta, case) * torch.as_tensor(case["advantages"])).mean().backward()
        failures.close(
            outputs[key],
            theta.grad.numpy(),
            f"batch {key[4:]}: the gradient (w's components, then "
            "log sigma's) must equal autograd's gradient of mean(log pi * A)",
            1e-7,
            1e-10,
        )
    return failures


def surrogate_inputs(rng: np.random.Generator) -> dict:
    """A batch evaluated at theta_old itself, and two evaluated at a theta moved away from it."""
    cases = {}
    for k in range(3):
        theta_old = _theta(rng)
        theta = theta_old if k == 0 else theta_old + rng.normal(0.0, 0.3, 4)
        cases[f"case{k}"] = {"theta": theta, "theta_old": theta_old, **_bandit_case(rng, theta_old, 50)}
    return cases


def surrogate_probe(namespace: dict, inputs: dict) -> dict:
    out = {}
    for key, case in inputs.items():
        theta = torch.tensor(case["theta"], dtype=torch.float64, requires_grad=True)
        value = namespace["surrogate"](
            theta, np.array(case["theta_old"]), case["states"], case["actions"], case["advantages"]
        )
        got = {"scalar": torch.is_tensor(value) and value.ndim == 0}
        if got["scalar"]:
            grad = torch.autograd.grad(value, theta, allow_unused=True)[0] if value.requires_grad else None
            got.update(
                value=value,
                differentiable=grad is not None,
                grad=torch.zeros(4, dtype=torch.float64) if grad is None else grad,
            )
        out[key] = got
    return out


def surrogate_verdict(inputs: dict, outputs: dict) -> list[str]:
    failures = Failures()
    for key in _cases(inputs):
        case, got, where = inputs[key], outputs[key], f"batch {key[4:]}"
        if not failures.true(got["scalar"], f"{where}: return L as a torch scalar (a 0-d tensor)"):
            continue
        theta = torch.tensor(case["theta"], requires_grad=True)
        ratio = torch.exp(_log_density(theta, case) - _log_density(torch.as_tensor(case["theta_old"]), case))
        value = (ratio * torch.as_tensor(case["advantages"])).mean()
        at_old = " (at theta_old every ratio is 1)" if key == "case0" else ""
        failures.close(got["value"], value.item(), f"{where}: the value of L{at_old}", 1e-10 if at_old else 1e-9, 1e-13)
        if failures.true(got["differentiable"], f"{where}: autograd must differentiate L with respect to theta"):
            failures.close(
                got["grad"],
                torch.autograd.grad(value, theta)[0].numpy(),
                f"{where}: the gradient of L" + (", the policy gradient g" if at_old else ""),
                1e-7,
                1e-10,
            )
    return failures


def cg_inputs(rng: np.random.Generator) -> dict:
    """Systems A x = b of 2, 5 and 8-20 unknowns, A = M M^T + n I."""
    cases = {}
    for k, n in enumerate((2, 5, int(rng.integers(8, 21)))):
        m = rng.standard_normal((n, n))
        cases[f"case{k}"] = {"A": m @ m.T + n * np.eye(n), "b": rng.standard_normal(n)}
    return cases


def cg_probe(namespace: dict, inputs: dict) -> dict:
    out = {}
    for key, case in inputs.items():
        matrix = torch.as_tensor(case["A"], dtype=torch.float64)
        got = {}
        for iters in CG_ITERS:
            b = torch.as_tensor(case["b"], dtype=torch.float64).clone()
            got[f"iters{iters}"] = namespace["my_cg"](lambda v: matrix @ v, b, iters)
            got[f"b_after{iters}"] = b
        out[key] = got
    return out


def cg_verdict(inputs: dict, outputs: dict) -> list[str]:
    failures = Failures()
    for key in _cases(inputs):
        case, got = inputs[key], outputs[key]
        matrix, b = torch.as_tensor(case["A"]), torch.as_tensor(case["b"])
        n = len(case["b"])
        for iters in CG_ITERS:
            where = f"system {key[4:]} ({n} unknowns), {iters} iteration{'s' if iters > 1 else ''}"
            failures.close(
                got[f"iters{iters}"],
                conjugate_gradient(lambda v: matrix @ v, b, iters).numpy(),
                f"{where}: x",
                1e-7,
                1e-7,
            )
            failures.true(np.array_equal(got[f"b_after{iters}"], case["b"]), f"{where}: my_cg must not change b")
    return failures


def _bare_policy(obs_dim: int, act_dim: int, hidden, init_std: float, seed: int = 0) -> GaussianPolicy:
    """A small Gaussian MLP policy (:func:`~vdtutorial.policy.make_policy`, kind "mlp") initialised from ``seed``,
    leaving torch's global generator as it was (the kernel's later cells draw from it)."""
    with torch.random.fork_rng():
        torch.manual_seed(seed)
        return make_policy(
            gym.spaces.Box(-1.0, 1.0, (obs_dim,), np.float32),
            act_dim,
            kind="mlp",
            init_std=init_std,
            scene_hidden=tuple(int(h) for h in np.atleast_1d(hidden)),
        )


def _policy(case: dict) -> GaussianPolicy:
    """The case's policy: its sizes, with the parameters' arrays the grader drew."""
    policy = _bare_policy(int(case["obs_dim"]), int(case["act_dim"]), case["hidden"], float(case["init_std"]))
    with torch.no_grad():
        for name, p in policy.named_parameters():
            p.copy_(torch.as_tensor(case["params"][name]))
    return policy


def _policy_case(rng, obs_dim, act_dim, hidden, init_std) -> dict:
    """A policy's sizes and arrays: a fresh initialisation (seeded from ``rng``), every parameter then moved at
    random, so that the mean and sigma depend on the state."""
    policy = _bare_policy(obs_dim, act_dim, hidden, init_std, int(rng.integers(2**31)))
    params = {}
    for name, p in policy.named_parameters():
        value = p.detach().numpy().astype(np.float64)
        params[name] = (value + rng.normal(0.0, 0.2, value.shape)).astype(np.float32)
    return {"obs_dim": obs_dim, "act_dim": act_dim, "hidden": np.array(hidden), "init_std": init_std, "params": params}


def _old(policy: GaussianPolicy, obs: torch.Tensor) -> Normal:
    with torch.no_grad():
        dist = policy.distribution(obs)
        return Normal(dist.mean.clone(), dist.stddev.clone())


def fvp_inputs(rng: np.random.Generator) -> dict:
    """Two small policies (one with two action dimensions), their states, and for each of two dampings (0 and a
    random one) three vectors to multiply."""
    cases = {}
    for k, (obs_dim, act_dim, hidden, n) in enumerate(((3, 1, (4,), 64), (5, 2, (6,), 20))):
        case = _policy_case(rng, obs_dim, act_dim, hidden, float(rng.uniform(0.3, 0.8)))
        n_params = sum(np.size(p) for p in case["params"].values())
        case.update(
            states=rng.uniform(-1.0, 1.0, (n, obs_dim)).astype(np.float32),
            dampings=np.array([0.0, 10 ** rng.uniform(-3, -1)]),
            vectors=rng.standard_normal((3, n_params)).astype(np.float32),
        )
        cases[f"case{k}"] = case
    return cases


def fvp_probe(namespace: dict, inputs: dict) -> dict:
    out = {}
    for key, case in inputs.items():
        policy = _policy(case)
        params = [p for p in policy.parameters() if p.requires_grad]
        states = torch.as_tensor(case["states"])
        old, vectors = _old(policy, states), torch.as_tensor(case["vectors"])
        got = {}
        for j, damping in enumerate(case["dampings"]):
            product = namespace["my_fvp"](policy, params, states, old, float(damping))
            got[f"damping{j}"] = {
                "products": torch.stack([product(v) for v in vectors]),
                "again": product(2 * vectors[0]),
            }
        out[key] = got
    return out


def fvp_verdict(inputs: dict, outputs: dict) -> list[str]:
    failures = Failures()
    for key in _cases(inputs):
        case = inputs[key]
        policy = _policy(case)
        params = [p for p in policy.parameters() if p.requires_grad]
        states = torch.as_tensor(case["states"])
        vectors = torch.as_tensor(case["vectors"])
        for j, damping in enumerate(case["dampings"]):
            got, where = outputs[key][f"damping{j}"], f"policy {key[4:]}, " + ("no damping" if j == 0 else "damping")
            product = double_backward_fvp(policy, params, states, _old(policy, states), float(damping))
            want = torch.stack([product(v) for v in vectors]).detach().numpy()
            failures.close(got["products"], want, f"{where}: (F + damping I) v", 1e-4, 1e-6)
            failures.close(
                got["again"],
                2 * want[0],
                f"{where}: the product must work again on another vector (keep the graph of the KL's gradient)",
                1e-4,
                1e-6,
            )
    return failures


def gae_inputs(rng: np.random.Generator) -> dict:
    """Reward sequences of 20-40 steps with episode ends (at least one before the last step), for lambda 0.95, 1
    and 0 and a random (gamma, lambda); and one step that ends its episode."""
    settings = ((0.99, 0.95), (0.9, 1.0), (0.99, 0.0), (rng.uniform(0.8, 1.0), rng.uniform(0.0, 1.0)))
    cases = {}
    for k, (gamma, lam) in enumerate(settings):
        steps = int(rng.integers(20, 41))
        dones = (rng.random(steps) < 0.15).astype(float)
        dones[rng.integers(0, steps - 1)] = 1.0
        cases[f"case{k}"] = {
            "rewards": rng.normal(size=steps),
            "values": rng.normal(size=steps),
            "last_value": rng.normal(),
            "dones": dones,
            "gamma": gamma,
            "lam": lam,
        }
    cases["case4"] = {
        "rewards": rng.normal(size=1),
        "values": rng.normal(size=1),
        "last_value": rng.normal(),
        "dones": np.ones(1),
        "gamma": 0.99,
        "lam": 0.95,
    }
    return cases


def gae_probe(namespace: dict, inputs: dict) -> dict:
    return {
        key: namespace["my_gae"](
            case["rewards"],
            case["values"],
            float(case["last_value"]),
            case["dones"],
            float(case["gamma"]),
            float(case["lam"]),
        )
        for key, case in inputs.items()
    }


def gae_verdict(inputs: dict, outputs: dict) -> list[str]:
    failures = Failures()
    for key in _cases(inputs):
        case = inputs[key]
        want = gae(
            case["rewards"],
            case["values"],
            float(case["last_value"]),
            case["dones"],
            float(case["gamma"]),
            float(case["lam"]),
        )
        what = (
            "one step that ends its episode: the advantage is the reward minus V"
            if key == "case4"
            else f"sequence {key[4:]}: the advantages"
        )
        failures.close(outputs[key], want, what, 1e-7, 1e-12)
    return failures


def baseline_inputs(rng: np.random.Generator) -> dict:
    """Four regressions: 1-5 features, small and large ridge terms, features scaled so that the clipping at +-10
    matters, and timesteps up to 25 (as floats) or up to 200 (as integers)."""
    cases = {}
    for k, (n_features, reg, scale, horizon) in enumerate(
        ((3, 1e-5, 1.0, 200), (1, 1e-5, 1.0, 25), (5, 10.0, 1.0, 25), (2, 1e-3, 30.0, 25))
    ):
        n = int(rng.integers(60, 81))
        features = scale * rng.normal(size=(n, n_features))
        timesteps = rng.integers(0, horizon, n)
        returns = rng.normal(size=n) + features[:, 0].clip(-10, 10) - timesteps / 50
        cases[f"case{k}"] = {
            "features": features,
            "timesteps": timesteps if k == 0 else timesteps.astype(float),
            "returns": returns,
            "reg": reg * 10 ** rng.uniform(-0.5, 0.5),
        }
    return cases


def baseline_probe(namespace: dict, inputs: dict) -> dict:
    return {
        key: namespace["fit_linear_baseline"](case["features"], case["timesteps"], case["returns"], float(case["reg"]))
        for key, case in inputs.items()
    }


def baseline_verdict(inputs: dict, outputs: dict) -> list[str]:
    failures = Failures()
    for key in _cases(inputs):
        case = inputs[key]
        reference = LinearFeatureBaseline(float(case["reg"]))
        reference.fit(case["features"], case["timesteps"], case["returns"])
        failures.close(
            outputs[key],
            reference.weights,
            f"regression {key[4:]}: the weights (one per column of phi, "
            "in the equation's order; f clipped, t divided by 100, the ridge term)",
            1e-6,
            1e-8,
        )
    return failures


def line_search_inputs(rng: np.random.Generator) -> dict:
    """Sixteen toy problems in 2-6 dimensions: a concave surrogate with slope +-g at theta_old, a KL that is 0.8 x
    its quadratic model plus a quartic term, and the direction F^-1 g. The trust regions, the quartic terms and the
    slopes' signs vary, so that the full step is accepted, backtracked from, or every fraction rejected."""
    cases = {}
    for k in range(16):
        dim = int(rng.integers(2, 7))
        b = rng.standard_normal((dim, dim))
        fisher, g = b @ b.T + 0.5 * np.eye(dim), rng.standard_normal(dim)
        cases[f"case{k}"] = {
            "theta": rng.standard_normal(dim),
            "g": g,
            "F": fisher,
            "direction": np.linalg.solve(fisher, g),
            "gain_sign": -1.0 if k % 5 == 4 else 1.0,
            "curvature": [0.0, 5.0, 500.0][k % 3] * rng.uniform(0.5, 2.0),
            "max_kl": [0.01, 0.1, 1.0][k % 3] * rng.uniform(0.5, 2.0),
            "backtrack_coeff": [0.5, 0.8][k % 2],
            "backtrack_iters": 3 if k % 4 == 0 else 10,
        }
    return cases


def _toy_problem(case: dict):
    """The case's parameter (theta_old), its surrogate_and_kl() and its Fisher-vector product."""
    theta = torch.nn.Parameter(torch.as_tensor(case["theta"], dtype=torch.float64).clone())
    theta_old = theta.detach().clone()
    g, fisher = torch.as_tensor(case["g"], dtype=torch.float64), torch.as_tensor(case["F"], dtype=torch.float64)
    sign, curvature = float(case["gain_sign"]), float(case["curvature"])

    def surrogate_and_kl():
        d = theta - theta_old
        return sign * (g @ d) - 2 * (d @ d), 0.4 * d @ fisher @ d + curvature * (d @ d) ** 2

    return theta, surrogate_and_kl, lambda v: fisher @ v


def _search_config(case: dict) -> TRPOConfig:
    return TRPOConfig(
        max_kl=float(case["max_kl"]),
        backtrack_coeff=float(case["backtrack_coeff"]),
        backtrack_iters=int(case["backtrack_iters"]),
    )


def _search_outcome(fraction, improvement, kl, params) -> dict:
    return {
        "rejected": fraction is None,
        "fraction": math.nan if fraction is None else float(fraction),
        "improvement": float(improvement),
        "kl": float(kl),
        "params": torch.cat([p.detach().reshape(-1) for p in params]),
    }


def line_search_probe(namespace: dict, inputs: dict) -> dict:
    out = {}
    for key, case in inputs.items():
        theta, surrogate_and_kl, fvp = _toy_problem(case)
        direction = torch.as_tensor(case["direction"], dtype=torch.float64)
        result = namespace["my_line_search"]([theta], direction, fvp, surrogate_and_kl, _search_config(case))
        out[key] = _search_outcome(*result, [theta])
    return out


def _compare_outcome(failures: Failures, got: dict, want: dict, where: str, tolerances: dict) -> None:
    """The line search's outcome (accepted fraction or rejection, improvement, KL, parameters) against the
    library's. ``tolerances``: (rtol, atol) of the numbers and of the parameters."""
    if not failures.true(
        bool(got["rejected"]) == want["rejected"],
        f"{where}: accept the first fraction whose true mean KL is within max_kl and whose "
        "surrogate rose; when none does, reject (return None)",
    ):
        return
    if not want["rejected"]:
        failures.close(got["fraction"], want["fraction"], f"{where}: the accepted fraction", 1e-12, 0)
    failures.close(
        got["improvement"], want["improvement"], f"{where}: the surrogate's improvement", *tolerances["stats"]
    )
    failures.close(got["kl"], want["kl"], f"{where}: the mean KL", *tolerances["stats"])
    failures.close(
        got["params"],
        want["params"],
        f"{where}: the parameters must be left at the accepted point (at theta_old when the step is rejected)",
        *tolerances["params"],
    )


def line_search_verdict(inputs: dict, outputs: dict) -> list[str]:
    failures = Failures()
    for key in _cases(inputs):
        case, config = inputs[key], _search_config(inputs[key])
        theta, surrogate_and_kl, fvp = _toy_problem(case)
        direction = torch.as_tensor(case["direction"], dtype=torch.float64)
        want = _search_outcome(*_reference_line_search([theta], direction, fvp, surrogate_and_kl, config), [theta])
        _compare_outcome(
            failures, outputs[key], want, f"problem {key[4:]}", {"stats": (1e-9, 1e-12), "params": (1e-7, 1e-7)}
        )
    return failures


def update_inputs(rng: np.random.Generator) -> dict:
    """Five batches of 96-160 random states, actions and normalised advantages for small policies (3 or 4
    observations, 1 or 2 actions), with the old hidden tests' configurations, a trust region so wide that the
    line search backtracks, and a line search allowed no try (so the step is rejected)."""
    configs = (
        {"max_kl": 0.01},
        {"max_kl": 0.002, "cg_iters": 5},
        {"max_kl": 0.05, "backtrack_coeff": 0.8},
        {"max_kl": 2.0, "cg_damping": 0.01},
        {"max_kl": 0.01, "backtrack_iters": 0},
    )
    cases = {}
    for k, config in enumerate(configs):
        obs_dim, act_dim, n = int(rng.integers(3, 5)), 1 + k % 2, int(rng.integers(96, 161))
        case = _policy_case(rng, obs_dim, act_dim, (8, 8), float(rng.uniform(0.5, 1.0)))
        advantages = rng.standard_normal(n)
        case.update(
            obs=rng.uniform(-1.0, 1.0, (n, obs_dim)).astype(np.float32),
            actions=rng.normal(0.0, 0.8, (n, act_dim)).astype(np.float32),
            advantages=((advantages - advantages.mean()) / advantages.std()).astype(np.float32),
            config=config,
        )
        cases[f"case{k}"] = case
    return {**cases, "stand_in": _stand_in_source()}


def _update_config(case: dict) -> TRPOConfig:
    return TRPOConfig(**{name: value.item() for name, value in case["config"].items()})


def _reference_line_search(params, direction, fvp, surrogate_and_kl, config):
    """Exercise 6.7's contract met by the library: the step scaled to the trust region's edge, then
    :func:`~vdtutorial.trust_region.line_search`."""
    full_step = math.sqrt(2 * config.max_kl / (direction @ fvp(direction)).item()) * direction
    return line_search(
        params, full_step, surrogate_and_kl, config.max_kl, config.backtrack_iters, config.backtrack_coeff
    )


def _stand_in_source() -> str:
    """The source of the line search that 6.8's check runs in place of the student's: the library's
    :func:`~vdtutorial.trust_region.line_search`, read where the library is whole (the grader's process, or a
    notebook checking itself), and :func:`_reference_line_search` around it. It travels as text in 6.8's inputs:
    in the grading kernel the library's line search is a stub (:mod:`vdtutorial.course.stubs`), and 6.8's inputs
    reach the kernel only after 6.7's outputs left it (``vdtutorial.course.classroom._Exchange``), so it cannot
    serve as a 6.7 answer."""
    head = "\n".join(
        [
            "from __future__ import annotations",
            "import math",
            "import torch",
            "from vdtutorial.trust_region import set_flat_params",
        ]
    )
    return "\n\n".join([head, inspect.getsource(line_search), inspect.getsource(_reference_line_search)])


def update_probe(namespace: dict, inputs: dict) -> dict:
    """The student's update, with the library's line search in place of theirs while it runs: each exercise is
    judged on its own, so a wrong 6.7 costs 6.7's points only (whether it also spoils an update depends on the
    drawn batch). The line search comes as text with the inputs (:func:`_stand_in_source`)."""
    code = {}
    exec(compile(str(inputs["stand_in"]), "<6.8's stand-in line search>", "exec"), code)  # the grader's own text
    missing = object()
    own = namespace.get("my_line_search", missing)
    namespace["my_line_search"] = code["_reference_line_search"]
    try:
        return _update_outcomes(namespace, {key: case for key, case in inputs.items() if key.startswith("case")})
    finally:
        if own is missing:
            del namespace["my_line_search"]
        else:
            namespace["my_line_search"] = own


def _update_outcomes(namespace: dict, inputs: dict) -> dict:
    out = {}
    for key, case in inputs.items():
        policy = _policy(case)
        params = [p for p in policy.parameters() if p.requires_grad]
        tensors = [torch.as_tensor(case[name]) for name in ("obs", "actions", "advantages")]
        stats = namespace["my_trpo_update"](policy, params, *tensors, _update_config(case))
        keys = [isinstance(stats, dict) and name in stats for name in STEP_STATS]
        out[key] = {"keys": keys}
        if all(keys):
            fraction = None if isinstance(stats["line_search"], str) else stats["line_search"]
            out[key].update(
                _search_outcome(fraction, stats["surrogate_improvement"], stats["mean_kl"], params),
                entropy=float(stats["entropy"]),
                label=str(stats["line_search"]) if fraction is None else "",
            )
    return out


@functools.lru_cache(maxsize=1)
def _env():
    """An environment for :class:`~vdtutorial.trpo.TRPO` to hold: its update never steps it."""
    return make_vec_env("Pendulum-v1", 1)


def _library_update(case: dict, config: TRPOConfig, sign: float = 1.0) -> tuple[dict, dict]:
    """:meth:`vdtutorial.trpo.TRPO.update` under ``config`` on the case's batch, its advantages times ``sign``, from
    the case's policy: its statistics and its outcome (:func:`_search_outcome`)."""
    algo = TRPO(_policy(case), _env(), config)
    n = len(case["advantages"])
    stats = algo.update(
        Batch(
            torch.as_tensor(case["obs"]),
            torch.as_tensor(case["actions"]),
            sign * torch.as_tensor(case["advantages"]),
            features=np.zeros((n, 1)),
            timesteps=np.zeros(n),
            returns=np.zeros(n),
            episode_returns=[],
            successes=0,
        )
    )
    fraction = None if stats["line_search"] == "rejected" else stats["line_search"]
    return stats, _search_outcome(fraction, stats["surrogate_improvement"], stats["mean_kl"], algo.params)


def _named_slip(case: dict, got: dict, want: dict) -> str | None:
    """What an update that left the parameters elsewhere than the library's did, when it is one of the two slips
    whose numbers alone say little (a line-search fraction, a mean KL slightly off): a step downhill on the
    surrogate (its sign), or the library's step solved without damping. ``None``: neither, or no slip."""
    tolerance = {"rtol": 1e-4, "atol": 1e-6}
    if np.allclose(got["params"], want["params"], **tolerance):
        return None
    start = torch.cat([p.detach().reshape(-1) for p in _policy(case).parameters() if p.requires_grad]).numpy()
    if float((np.asarray(got["params"]) - start) @ (np.asarray(want["params"]) - start)) < 0:
        return (
            "the step went downhill on the surrogate, the opposite way to the library's: check the sign of your "
            "surrogate, L = mean(pi_theta / pi_old * A), which the update maximises"
        )
    undamped = _library_update(case, dataclasses.replace(_update_config(case), cg_damping=0.0))[1]
    if np.allclose(got["params"], undamped["params"], **tolerance):
        return (
            "the step is the one solved without damping: the Fisher-vector products of the direction's solve "
            "must be (F + config.cg_damping I) v"
        )
    return None


def update_verdict(inputs: dict, outputs: dict) -> list[str]:
    failures = Failures()
    for key in _cases(inputs):
        case, got, where = inputs[key], outputs[key], f"batch {key[4:]}"
        if not failures.true(got["keys"], f"{where}: return a dict with the keys {', '.join(STEP_STATS)}"):
            continue
        stats, want = _library_update(case, _update_config(case))
        slip = _named_slip(case, got, want)
        if slip:
            failures.append(f"{where}: {slip}")
            continue
        if want["rejected"]:
            failures.true(str(got["label"]) == "rejected", f'{where}: a rejected step\'s line_search is "rejected"')
        failures.close(got["entropy"], stats["entropy"], f"{where}: the entropy of pi_old", 1e-4, 1e-7)
        _compare_outcome(failures, got, want, where, {"stats": (1e-4, 1e-7), "params": (1e-4, 1e-6)})
    return failures


CHECKS = [
    Check("ch06_reinforce", reinforce_inputs, reinforce_probe, reinforce_verdict),
    Check("ch06_surrogate", surrogate_inputs, surrogate_probe, surrogate_verdict),
    Check("ch06_conjugate_gradient", cg_inputs, cg_probe, cg_verdict),
    Check("ch06_fisher_vector_product", fvp_inputs, fvp_probe, fvp_verdict),
    Check("ch06_gae", gae_inputs, gae_probe, gae_verdict),
    Check("ch06_linear_baseline", baseline_inputs, baseline_probe, baseline_verdict),
    Check("ch06_line_search", line_search_inputs, line_search_probe, line_search_verdict),
    Check("ch06_trpo_update", update_inputs, update_probe, update_verdict),
]
