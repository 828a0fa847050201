"""agents.activations.Tanh is torch's tanh (values and gradients), through a faster kernel."""

from __future__ import annotations

import torch
from torch import nn

from agents.activations import Tanh
from agents.train import build_model_kwargs


def test_tanh_values_and_gradient_match_torch() -> None:
    x = torch.linspace(-25.0, 25.0, 200_001, dtype=torch.float32)
    exact = torch.tanh(x.double())
    assert (Tanh()(x).double() - exact).abs().max().item() < 3e-7
    xa = x.clone().requires_grad_(True)
    xb = x.clone().requires_grad_(True)
    g = torch.randn(x.shape, generator=torch.Generator().manual_seed(0))
    Tanh()(xa).backward(g)
    torch.tanh(xb).backward(g)
    # both backward passes are g (1 - y^2); the two y differ by < 3e-7 + 6e-8, so (1 - y^2) by < 1e-6
    diff = (xa.grad - xb.grad).abs()  # type: ignore[operator]
    assert bool((diff <= 1e-6 * g.abs() + 1e-7).all()), diff.max()
    assert isinstance(Tanh(), nn.Tanh)


def test_config_tanh_builds_the_fast_kernel() -> None:
    kw = build_model_kwargs("ppo", {"hyperparams": {"policy_kwargs": {"activation_fn": "tanh"}}}, 1)
    assert kw["policy_kwargs"]["activation_fn"] is Tanh
    kw = build_model_kwargs("ppo", {"hyperparams": {"policy_kwargs": {"activation_fn": "torch_tanh"}}}, 1)
    assert kw["policy_kwargs"]["activation_fn"] is nn.Tanh
