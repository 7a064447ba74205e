#!/usr/bin/env python3
"""Forward + backward cost of the hidden-layer normalisations on [B, C, T] conv activations
at the batched MAML step's shapes (docs/training.md, "A LayerNorm over channels instead of
BatchNorm"). Usage: <test venv python> scripts/bench_layer_norm.py [threads]"""
import sys
import time

import torch

torch.set_num_threads(int(sys.argv[1]) if len(sys.argv) > 1 else 1)
B, T = 18, 3500
def ln_t(h, g, b):
    return torch.nn.functional.layer_norm(h.transpose(1, 2), (h.shape[1],), g, b, 1e-5).transpose(1, 2)
def ln_manual(h, g, b):
    m = h.mean(1, keepdim=True); v = (h - m).pow(2).mean(1, keepdim=True)
    return (h - m) * torch.rsqrt(v + 1e-5) * g[:, None] + b[:, None]
def ln_group(h, g, b):
    # The same LayerNorm through var_mean and addcmul.
    v, m = torch.var_mean(h, 1, unbiased=False, keepdim=True)
    return torch.addcmul(b[:, None], (h - m) * torch.rsqrt(v + 1e-5), g[:, None])
def bn(h, g, b, rm, rv):
    return torch.nn.functional.batch_norm(h, rm, rv, g, b, True, 0.1, 1e-5)
for C in (16, 32, 64, 128):
    h0 = torch.randn(B, C, T)
    g = torch.ones(C, requires_grad=True); b = torch.zeros(C, requires_grad=True)
    rm, rv = torch.zeros(C), torch.ones(C)
    res = {}
    for name, f in [('bn', lambda h: bn(h, g, b, rm, rv)), ('ln_transpose', lambda h: ln_t(h, g, b)), ('ln_manual', lambda h: ln_manual(h, g, b)), ('ln_var_mean', lambda h: ln_group(h, g, b))]:
        best = 1e9
        for rep in range(5):
            h = h0.clone().requires_grad_(True)
            t = time.perf_counter()
            y = torch.nn.functional.gelu(f(h)); y.sum().backward()
            best = min(best, time.perf_counter() - t)
        res[name] = best * 1e3
    print(f"C={C:4d} " + "  ".join(f"{k} {v:6.1f} ms" for k, v in res.items()))
h = torch.randn(2, 16, 50); print('check', (ln_t(h, g[:16], b[:16]) - ln_manual(h, g[:16], b[:16])).abs().max().item(), (ln_t(h, g[:16], b[:16]) - ln_group(h, g[:16], b[:16])).abs().max().item())
