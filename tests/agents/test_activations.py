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


def test_the_forward_without_gradient_is_the_same_function_bit_for_bit() -> None:
    x = torch.linspace(-25.0, 25.0, 10_001, dtype=torch.float32).reshape(-1, 1)
    with torch.no_grad():
        fast = Tanh()(x)
    recorded = Tanh()(x.clone().requires_grad_(True))
    assert recorded.grad_fn is not None
    assert torch.equal(fast, recorded.detach())


def test_ppo_s_adam_is_sb3_s_with_the_multi_tensor_update_bit_for_bit() -> None:
    kw = build_model_kwargs("ppo", {"hyperparams": {}}, 1)
    assert kw["policy_kwargs"]["optimizer_kwargs"] == {"eps": 1e-5, "foreach": True}  # SB3's eps for PPO's Adam
    own = {"optimizer_kwargs": {"eps": 1e-7}}
    assert build_model_kwargs("ppo", {"hyperparams": {"policy_kwargs": own}}, 1)["policy_kwargs"] == own
    assert "policy_kwargs" not in build_model_kwargs("sac", {"hyperparams": {}}, 1)
    gen = torch.Generator().manual_seed(0)
    shapes = [(64, 48), (64,), (64, 64), (64,), (1, 64), (1,), (1,)]
    init = [torch.randn(s, generator=gen) for s in shapes]
    grads = [[torch.randn(s, generator=gen) for s in shapes] for _ in range(20)]
    final = []
    for foreach in (False, True):
        ps = [nn.Parameter(p.clone()) for p in init]
        opt = torch.optim.Adam(ps, lr=1e-3, eps=1e-5, foreach=foreach)
        for gs in grads:
            for p, g in zip(ps, gs, strict=True):
                p.grad = g.clone()
            opt.step()
        final.append(torch.cat([p.detach().flatten() for p in ps]))
    assert torch.equal(final[0], final[1])
