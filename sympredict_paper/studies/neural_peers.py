"""Neural peers for the data-driven comparison (optional: ``pip install 'sympredict[bench]'`` installs PyTorch).

Both learn a flow map at one fixed macro step from the same ``(x0, mu) -> x1`` samples as the kernel models:

* :class:`MLPFlowMap`: ``x1 = x0 + N(x0, mu)``, a residual MLP (values only, not symplectic);
* :class:`GSympNet`: a parameter-conditioned G-SympNet (Jin et al., Neural Networks 2020): alternating
  "up" / "down" gradient modules ``p <- p + grad_q V(q; mu)``, ``q <- q + grad_p V(p; mu)`` with
  ``grad V(z; mu) = K^T (a * tanh(K z + W mu + b))``; each module is a shear whose Jacobian is symplectic
  for every fixed ``mu``, so the whole map is symplectic in ``(q, p)``.

Training: Adam on minibatches (cosine learning-rate decay) of the mean squared one-step error of scaled
states, a fixed number of epochs (about a minute per model on one CPU thread).  Online: one forward pass per step, batched.
"""

from __future__ import annotations

import time

import numpy as np
import torch

torch.set_default_dtype(torch.float64)


class _Net(torch.nn.Module):
    def predict(self, x, mu):
        raise NotImplementedError


class _MLP(_Net):
    def __init__(self, dim, n_mu, width, depth):
        super().__init__()
        layers, d = [], dim + n_mu
        for _ in range(depth):
            layers += [torch.nn.Linear(d, width), torch.nn.Tanh()]
            d = width
        layers.append(torch.nn.Linear(d, dim))
        self.net = torch.nn.Sequential(*layers)

    def forward(self, x, mu):
        return x + self.net(torch.cat([x, mu], dim=1))


class _GSymp(_Net):
    def __init__(self, dim, n_mu, width, n_modules):
        super().__init__()
        n = dim // 2
        self.n = n
        self.K = torch.nn.ParameterList([torch.nn.Parameter(torch.randn(width, n) * 0.5) for _ in range(n_modules)])
        self.W = torch.nn.ParameterList([torch.nn.Parameter(torch.randn(width, n_mu) * 0.5) for _ in range(n_modules)])
        self.b = torch.nn.ParameterList([torch.nn.Parameter(torch.zeros(width)) for _ in range(n_modules)])
        self.a = torch.nn.ParameterList([torch.nn.Parameter(torch.randn(width) * 0.01) for _ in range(n_modules)])

    def forward(self, x, mu):
        q, p = x[:, : self.n], x[:, self.n :]
        for i, (K, W, b, a) in enumerate(zip(self.K, self.W, self.b, self.a)):
            z = q if i % 2 == 0 else p
            g = (a * torch.tanh(z @ K.T + mu @ W.T + b)) @ K
            if i % 2 == 0:
                p = p + g
            else:
                q = q + g
        return torch.cat([q, p], dim=1)


class _TorchFlowMap:
    """Common fit / rollout for the networks: scaled states and parameters, minibatch Adam."""

    def __init__(self, epochs: int = 100, batch_size: int = 256, lr: float = 3e-3, seed: int = 0, **arch):
        self.epochs, self.batch_size, self.lr, self.seed, self.arch = epochs, batch_size, lr, seed, arch

    def _build(self, dim, n_mu):
        raise NotImplementedError

    def fit(self, x0, x1, mu):
        torch.manual_seed(self.seed)
        mu = np.asarray(mu, dtype=float).reshape(len(x0), -1)
        # one scale for all states (a common scaling keeps the G-SympNet symplectic in the original variables)
        self.x_scale = float(np.abs(x0).max())
        self.mu_lo, self.mu_span = mu.min(axis=0), np.where(np.ptp(mu, axis=0) > 0, np.ptp(mu, axis=0), 1.0)
        X0 = torch.from_numpy(x0 / self.x_scale)
        X1 = torch.from_numpy(x1 / self.x_scale)
        M = torch.from_numpy((mu - self.mu_lo) / self.mu_span)
        self.net = self._build(x0.shape[1], mu.shape[1])
        opt = torch.optim.Adam(self.net.parameters(), lr=self.lr)
        n_batches = max(1, len(X0) // self.batch_size)
        sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, self.epochs * n_batches)
        t0 = time.perf_counter()
        for _ in range(self.epochs):
            perm = torch.randperm(len(X0))
            for idx in perm[: n_batches * self.batch_size].reshape(n_batches, -1):
                opt.zero_grad()
                loss = torch.mean((self.net(X0[idx], M[idx]) - X1[idx]) ** 2)
                loss.backward()
                opt.step()
                sched.step()
        with torch.no_grad():
            loss = torch.mean((self.net(X0, M) - X1) ** 2)
        self.fit_time_s_ = time.perf_counter() - t0
        self.final_loss_ = float(loss.detach())
        return self

    @torch.no_grad()
    def rollout(self, x0, n_steps, mu):
        mu = np.asarray(mu, dtype=float)
        mu = np.broadcast_to(
            mu.reshape(1, -1)
            if mu.ndim <= 1 and mu.size == len(self.mu_lo) and mu.size != len(x0)
            else mu.reshape(len(x0), -1),
            (len(x0), len(self.mu_lo)),
        )
        M = torch.from_numpy((mu - self.mu_lo) / self.mu_span)
        x = torch.from_numpy(np.asarray(x0, dtype=float) / self.x_scale)
        out = [x]
        for _ in range(n_steps):
            x = self.net(x, M)
            out.append(x)
        return torch.stack(out, dim=1).numpy() * self.x_scale


class MLPFlowMap(_TorchFlowMap):
    """Residual MLP flow map (values only, not symplectic): ``width`` x ``depth`` tanh layers."""

    def _build(self, dim, n_mu):
        return _MLP(dim, n_mu, self.arch.get("width", 64), self.arch.get("depth", 3))


class GSympNet(_TorchFlowMap):
    """Parameter-conditioned G-SympNet: ``n_modules`` gradient modules of ``width`` neurons (symplectic for every ``mu``)."""

    def _build(self, dim, n_mu):
        return _GSymp(dim, n_mu, self.arch.get("width", 32), self.arch.get("n_modules", 6))
