"""The paper's policy: a Gaussian N(mu_phi(s), sigma_psi(s)) whose mean and standard deviation are each
computed by the two-stream network of Fig. 2 (Section IV).

Network kinds (``PolicyNet``), chosen from the observation space by :func:`make_policy`
    ``"rgbd"``: the paper's network. Image stream: 3 convolutions (ReLU, no padding) and 3 fully
    connected layers; joint stream: 3 fully connected layers on the joint angles; both streams are
    concatenated into one final fully connected layer with one output per action dimension.
    ``"state"``: the same two streams with the convolutions dropped: the "image" stream is an MLP on the
    cup position (last 3 numbers of the vector observation), the joint stream reads the joint angles
    (the numbers before). The fast stand-in for the image network in classes and CI.
    ``"mlp"``: a single MLP stream on a generic vector observation (e.g. Pendulum-v1, used to validate
    TRPO), followed by the same final layer.
Every layer is a plain or a sparse variational dropout layer according to one flag, ``variational``.

Taught in chapter 05.
"""

from __future__ import annotations

import math
from contextlib import contextmanager

import gymnasium as gym
import numpy as np
import torch
import torch.nn.functional as F
from torch import nn
from torch.distributions import Normal

from vdtutorial.trust_region import mean_kl
from vdtutorial.vd import THRESHOLD, WEIGHT_LAYERS, make_conv2d, make_linear, prune_model

KINDS = ("rgbd", "state", "mlp")
#: Keys of the environments' image observation (see :class:`vdtutorial.envs.base.JacoEnv`).
IMAGE_KEYS = ("rgb", "depth", "joints")
#: Depth normaliser in metres: the environments clip depth at the camera's far plane, 3 m.
DEPTH_SCALE = 3.0
#: Number of trailing entries of a "state" observation that are the cup position (x, y, z).
CUP_DIMS = 3
#: Factor applied to the initial weights of the final layer (:class:`GaussianPolicy`, "Initialisation").
HEAD_INIT_SCALE = 0.1


def map_obs(fn, obs):
    """``fn`` applied to a batch of observations: the array or tensor, or each entry of a Dict observation."""
    return {key: fn(value) for key, value in obs.items()} if isinstance(obs, dict) else fn(obs)


def stack_obs(fn, observations: list):
    """``fn`` applied to a list of observations, entry by entry for dicts: e.g. ``np.stack`` makes one batch."""
    if isinstance(observations[0], dict):
        return {key: fn([o[key] for o in observations]) for key in observations[0]}
    return fn(observations)


def _as_tensor(x, device):
    tensor = torch.as_tensor(x, device=device)
    return tensor if tensor.dtype == torch.uint8 else tensor.to(torch.float32)


def obs_to_tensor(obs, device: torch.device | str | None = None):
    """Tensor(s) from a numpy array, a tensor, or a dict of either: uint8 images stay uint8 (a quarter of the memory;
    the network scales them), anything else becomes float32. ``device``: where they go (None: where they are)."""
    return map_obs(lambda x: _as_tensor(x, device), obs)


def torch_device(name: torch.device | str, option: str = "device") -> torch.device:
    """``name`` ("cpu", "cuda", "cuda:1", or a torch.device) as a ``torch.device`` this machine can run, else a
    one-line ValueError naming ``option`` (the command line's "--device"). Only pre-training and TRPO's update
    run on a GPU; environments, rollouts and checkpoints stay on the CPU."""
    try:
        device = torch.device(name)
    except RuntimeError:
        device = None
    if device is None or device.type not in ("cpu", "cuda"):
        raise ValueError(f"{option} {name}: expected cpu, cuda or cuda:N")
    if device.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"{option} {name}: this machine has no CUDA GPU (torch.cuda.is_available() is False)")
    if device.type == "cuda" and (device.index or 0) >= torch.cuda.device_count():
        raise ValueError(f"{option} {name}: this machine has {torch.cuda.device_count()} CUDA GPU(s)")
    return device


@contextmanager
def on_device(module: nn.Module, device: torch.device):
    """Run the ``with`` block with ``module`` on ``device``, then move it back to the CPU (also after an error).
    ``Module.to`` keeps the same Parameter objects (only their data moves), so lists of a module's parameters
    made before, such as TRPO's, stay valid."""
    module.to(device)
    try:
        yield module
    finally:
        module.to("cpu")


def _is_unbatched(obs) -> bool:
    """True when ``obs`` (tensor or dict of tensors) is one observation without a batch dimension."""
    return obs["rgb"].dim() == 3 if isinstance(obs, dict) else obs.dim() == 1


def image_shape(obs_shape: dict) -> tuple[int, int]:
    """(channels, side) of the network's input image: ``obs_shape["rgb"]`` is (3, S, S), plus one depth channel."""
    return obs_shape["rgb"][0] + 1, obs_shape["rgb"][-1]


def _angle_features(angles: torch.Tensor) -> torch.Tensor:
    return torch.cat([torch.sin(angles), torch.cos(angles)], dim=-1)


def _mlp(in_features: int, hidden, variational: bool) -> list[nn.Module]:
    layers = []
    for units in hidden:
        layers += [make_linear(in_features, units, variational), nn.Tanh()]
        in_features = units
    return layers


def _bounds_affine(low, high, dims: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Centre and half-width mapping [low, high] to [-1, 1]; (0, 1) where a bound is missing, infinite or
    the interval is empty."""
    if low is None or high is None:
        return torch.zeros(dims), torch.ones(dims)
    low, high = torch.as_tensor(low, dtype=torch.float32), torch.as_tensor(high, dtype=torch.float32)
    usable = torch.isfinite(low) & torch.isfinite(high) & (high > low)
    centre = torch.where(usable, (low + high) / 2, 0.0)
    half_width = torch.where(usable, (high - low) / 2, 1.0)
    return centre, half_width


class PolicyNet(nn.Module):
    """The network of Fig. 2, one each for mu and sigma (module docstring, "Network kinds"; inputs: below).

    ``streams[0]`` is the scene stream (image, cup position, or the whole vector for ``"mlp"``),
    ``streams[1]`` the joint stream (absent for ``"mlp"``); ``head`` is the final fully connected layer.

    obs_shape: ``{"rgb": (3, S, S), "depth": (S * S,), "joints": (J,)}`` for ``"rgbd"`` (see
        :func:`image_shape`), ``(d,)`` otherwise.
    out_dim: one output per action dimension.
    obs_low, obs_high: bounds of a vector observation (``"state"``, ``"mlp"``), for the normalisation.
    conv_channels, conv_kernels, conv_strides: the 3 convolutions of the image stream.
    scene_hidden: units of the fully connected layers of the scene stream; joint_hidden: of the joint stream.

    Input normalisation (inside the network, so checkpoints carry it)
        RGB (uint8) / 255 and depth / ``DEPTH_SCALE`` (the camera's 3 m far plane), both in [0, 1], are stacked
        into one 4-channel image and shifted by -0.5. Joint angles enter as (sin, cos) pairs: bounded, and
        continuous across the +-pi wrap of continuous joints. Other vector inputs (the cup position, a generic
        Box) are mapped from the space's bounds to [-1, 1]; dimensions with infinite or zero-width bounds pass
        through unchanged. (:mod:`vdtutorial.fast.policy` normalises a batch once for both networks.)

    Sizes: the paper does not give its layer sizes. The defaults are 8/16/16 channels with kernels 8/4/3 and
        strides 4/2/2 (128 -> 31 -> 14 -> 6 pixels, 576 features), then 64-64-32 units in each stream, sized
        for a laptop CPU with one thread per process (their cost: docs/results.md, "Measurements behind the code").
    """

    def __init__(
        self,
        kind: str,
        obs_shape,
        out_dim: int,
        variational: bool = False,
        *,
        obs_low=None,
        obs_high=None,
        conv_channels=(8, 16, 16),
        conv_kernels=(8, 4, 3),
        conv_strides=(4, 2, 2),
        scene_hidden=(64, 64, 32),
        joint_hidden=(64, 64, 32),
    ):
        super().__init__()
        if kind not in KINDS:
            raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
        self.kind = kind
        if kind == "rgbd":
            channels, size = image_shape(obs_shape)
            side = size
            scene = []
            for out, k, s in zip(conv_channels, conv_kernels, conv_strides):
                scene += [make_conv2d(channels, out, k, stride=s, variational=variational), nn.ReLU()]
                channels, size = out, (size - k) // s + 1
            if size < 1:
                raise ValueError(f"image of {side} pixels too small for the convolutions")
            scene += [nn.Flatten(), *_mlp(channels * size * size, scene_hidden, variational)]
            joints = _mlp(2 * obs_shape["joints"][0], joint_hidden, variational)
            streams = [scene, joints]
        elif kind == "state":
            self._register_bounds(obs_low, obs_high, slice(-CUP_DIMS, None), CUP_DIMS)
            streams = [
                _mlp(CUP_DIMS, scene_hidden, variational),
                _mlp(2 * (obs_shape[0] - CUP_DIMS), joint_hidden, variational),
            ]
        else:
            self._register_bounds(obs_low, obs_high, slice(None), obs_shape[0])
            streams = [_mlp(obs_shape[0], scene_hidden, variational)]
        self.streams = nn.ModuleList(nn.Sequential(*layers) for layers in streams)
        last_layers = [[m for m in stream if isinstance(m, WEIGHT_LAYERS)][-1] for stream in self.streams]
        features = sum(layer.weight.shape[0] for layer in last_layers)
        self.head = nn.Sequential(make_linear(features, out_dim, variational))

    def _register_bounds(self, low, high, part: slice, dims: int) -> None:
        def select(bound):
            return None if bound is None else np.asarray(bound, dtype=np.float32)[part]

        centre, half_width = _bounds_affine(select(low), select(high), dims)
        self.register_buffer("input_centre", centre)
        self.register_buffer("input_scale", half_width)

    def stream_inputs(self, obs) -> list[torch.Tensor]:
        """Each stream's normalised input for a batch of observations (tensors)."""
        if self.kind == "rgbd":
            # Written into one preallocated image, in place: the same divisions and subtraction as
            # cat([rgb / 255, depth / DEPTH_SCALE]) - 0.5 without the three temporary images.
            rgb = obs["rgb"]
            n, channels, height, width = rgb.shape
            image = torch.empty((n, channels + 1, height, width), dtype=torch.float32, device=rgb.device)
            torch.div(rgb, 255.0, out=image[:, :channels])
            image[:, channels:].copy_(obs["depth"].reshape(n, 1, height, width) / DEPTH_SCALE)
            return [image.sub_(0.5), _angle_features(obs["joints"])]
        if self.kind == "state":
            cup = (obs[..., -CUP_DIMS:] - self.input_centre) / self.input_scale
            return [cup, _angle_features(obs[..., :-CUP_DIMS])]
        return [(obs - self.input_centre) / self.input_scale]

    def forward(self, obs) -> torch.Tensor:
        features = [stream(x) for stream, x in zip(self.streams, self.stream_inputs(obs))]
        return self.head(torch.cat(features, dim=-1))


def _jsonable(value):
    """Tuples -> lists (recursively) so that a config survives JSON and compares equal after it."""
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (tuple, list, np.ndarray)):
        return [_jsonable(v) for v in value]
    return value.item() if isinstance(value, np.generic) else value


class GaussianPolicy(nn.Module):
    """pi(a | s) = N(mu(s), diag(sigma(s)^2)), with ``mu`` and ``sigma`` two :class:`PolicyNet` of the same
    kind (Section IV). The pre-training phase trains ``mu`` only; the RL phase trains both.

    kind, obs_shape, obs_low, obs_high: see :class:`PolicyNet`. action_dim: number of action dimensions.
    variational: sparse VD layers in both networks. sizes: keyword sizes of :class:`PolicyNet`.
    init_std: initial sigma (radians of joint-angle change for the Jaco tasks; the action range is
    +-pi/5 ~ +-0.63). min_std: floor of sigma.

    ``config`` holds every constructor argument, JSON-friendly; ``GaussianPolicy.from_config(config)``
    plus ``load_state_dict`` rebuilds a checkpoint (pruning masks included).

    Initialisation
        The final layer's weights of both networks are shrunk by ``HEAD_INIT_SCALE`` so that at the start
        the mean action is close to 0 and sigma is close to ``init_std`` whatever the observation. sigma =
        ``min_std`` + softplus(output): positive by construction, with a floor that keeps log-probabilities
        finite; the final bias of the sigma network is set so that sigma = ``init_std`` (default 0.3 rad) for
        a zero pre-activation. With sparse VD layers the shrunk final weights (|theta| <= 0.1 / sqrt(64))
        include ~10% below the "born pruned" size of :mod:`vdtutorial.vd` (|theta| < 0.0015): pre-training
        revives the useful ones in ``mu``; in the untrained ``sigma`` they are dropped by :meth:`prune_`.
    """

    def __init__(
        self,
        kind: str,
        obs_shape,
        action_dim: int,
        variational: bool = False,
        sizes: dict | None = None,
        init_std: float = 0.3,
        min_std: float = 0.01,
        obs_low=None,
        obs_high=None,
    ):
        super().__init__()
        if not init_std > min_std >= 0:
            raise ValueError(f"need init_std > min_std >= 0, got {init_std}, {min_std}")
        self.config = _jsonable(
            dict(
                kind=kind,
                obs_shape=obs_shape,
                action_dim=action_dim,
                variational=variational,
                sizes=dict(sizes or {}),
                init_std=init_std,
                min_std=min_std,
                obs_low=obs_low,
                obs_high=obs_high,
            )
        )
        self.min_std = min_std
        nets = [
            PolicyNet(kind, obs_shape, action_dim, variational, obs_low=obs_low, obs_high=obs_high, **(sizes or {}))
            for _ in range(2)
        ]
        self.mu, self.sigma = nets
        with torch.no_grad():
            for net in nets:
                net.head[0].weight.mul_(HEAD_INIT_SCALE)
            self.mu.head[0].bias.zero_()
            self.sigma.head[0].bias.fill_(math.log(math.expm1(init_std - min_std)))  # softplus^-1

    @classmethod
    def from_config(cls, config: dict) -> "GaussianPolicy":
        return cls(**config)

    def distribution(self, obs) -> Normal:
        """pi(. | s) for a batch of observations (tensor (B, d) or dict of batched tensors): N(mu(s), sigma(s)^2)
        with sigma = ``min_std`` + softplus of the sigma network's output."""
        obs = obs_to_tensor(obs)
        return Normal(self.mu(obs), self.min_std + F.softplus(self.sigma(obs)))

    def log_prob(self, obs, actions: torch.Tensor) -> torch.Tensor:
        """log pi(a | s) per observation, summed over action dimensions (independent Gaussians)."""
        return self.distribution(obs).log_prob(torch.as_tensor(actions, dtype=torch.float32)).sum(-1)

    def entropy(self, obs) -> torch.Tensor:
        """Entropy of pi(. | s) per observation."""
        return self.distribution(obs).entropy().sum(-1)

    def kl(self, old, obs) -> torch.Tensor:
        """Mean over ``obs`` of KL(old || self), the quantity TRPO constrains. ``old`` is a policy or the
        Normal it gave on ``obs``; it is treated as a constant (detached)."""
        if isinstance(old, GaussianPolicy):
            with torch.no_grad():
                old = old.distribution(obs)
        old = Normal(old.loc.detach(), old.scale.detach())
        return mean_kl(old, self.distribution(obs))

    @torch.no_grad()
    def sample(self, obs) -> torch.Tensor:
        """One action per observation of a batch."""
        return self.distribution(obs).sample()

    @torch.no_grad()
    def act(self, obs, deterministic: bool = False) -> np.ndarray:
        """Action(s) as numpy for one observation or a batch (array, or dict for ``"rgbd"``); the mean
        action when ``deterministic``. Uses the current train/eval mode: call ``eval()`` first to act with
        an unpruned sparse-VD policy without weight noise."""
        obs = obs_to_tensor(obs)
        single = _is_unbatched(obs)
        if single:
            obs = {k: v.unsqueeze(0) for k, v in obs.items()} if isinstance(obs, dict) else obs.unsqueeze(0)
        dist = self.distribution(obs)
        actions = (dist.mean if deterministic else dist.sample()).numpy()
        return actions[0] if single else actions

    def prune_(self, threshold: float = THRESHOLD) -> "GaussianPolicy":
        """Freeze the pruning masks of every sparse-VD layer (start of the RL phase, Section IV)."""
        prune_model(self, threshold)
        return self


def make_policy(
    observation_space,
    action_dim: int,
    variational: bool = False,
    kind: str = "auto",
    init_std: float = 0.3,
    min_std: float = 0.01,
    normalise: bool = True,
    **sizes,
) -> GaussianPolicy:
    """Gaussian policy for a gymnasium observation space.

    kind: ``"rgbd"`` (Dict with "rgb", "depth" and "joints"), ``"state"`` (Box of joint angles then cup x, y, z),
    ``"mlp"`` (any Box), or ``"auto"``: Dict -> "rgbd", Box of shape (9,) -> "state" (the Jaco
    environments' state mode: 6 joints + 3 cup coordinates), any other Box -> "mlp". Pass ``kind="mlp"``
    explicitly for a 9-number Box that is not a Jaco state. ``sizes``: see :class:`PolicyNet`.
    normalise: map a vector observation from the space's bounds to [-1, 1] (:class:`PolicyNet`); False feeds
    it as it is. The bounds suit the Jaco tasks, where they are the joints' and the cup's ranges; a bound that is
    a loose clip shrinks what the policy sees (Pendulum-v1's angular velocity: +-8 rad/s, see
    :func:`vdtutorial.experiments.pendulum.pendulum_policy`).
    """
    is_dict = isinstance(observation_space, gym.spaces.Dict)
    if kind == "auto":
        kind = "rgbd" if is_dict else "state" if observation_space.shape == (9,) else "mlp"
    if kind == "rgbd":
        if not is_dict or not set(IMAGE_KEYS) <= set(observation_space.spaces):
            raise ValueError(f"kind 'rgbd' needs a Dict space with keys {IMAGE_KEYS}, got {observation_space}")
        obs_shape = {key: observation_space[key].shape for key in IMAGE_KEYS}
        bounds = {}
    else:
        if is_dict or len(observation_space.shape) != 1:
            raise ValueError(f"kind {kind!r} needs a 1-D Box space, got {observation_space}")
        obs_shape = observation_space.shape
        bounds = dict(obs_low=observation_space.low, obs_high=observation_space.high) if normalise else {}
    return GaussianPolicy(kind, obs_shape, action_dim, variational, sizes, init_std, min_std, **bounds)
