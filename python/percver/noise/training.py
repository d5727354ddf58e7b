"""The torch side of the noise models: the lazy import, dense modules, the training loop, export.

torch is imported only when a model is trained (``pip install "percver[train]"``); a trained model
is a :class:`percver.Network`, evaluated with numpy, written as ONNX and read back by
:func:`percver.load_network`.
"""

from __future__ import annotations

import copy
import sys
import time

import numpy as np

from percver.errors import InputError, MissingDependencyError


def require_torch(purpose: str = "training noise models"):
    """The torch module, or a clear error naming the extra to install."""
    try:
        import torch
    except ImportError:
        raise MissingDependencyError(f'{purpose} needs torch: pip install "percver[train]"') from None
    return torch


def mlp(torch, sizes, hidden_activation, output_activation=None):
    """Dense layers of ``sizes`` (inputs, hidden..., outputs) with torch activation classes between them."""
    layers = []
    for k, (n_in, n_out) in enumerate(zip(sizes[:-1], sizes[1:])):
        layers.append(torch.nn.Linear(n_in, n_out))
        last = k == len(sizes) - 2
        if not last or output_activation is not None:
            layers.append((output_activation if last else hidden_activation)())
    return torch.nn.Sequential(*layers)


def to_network(module, name: str, *, scale=None, offset=None, inputs=None):
    """A torch ``Sequential`` of Linear / Tanh / Sigmoid / ReLU layers as a ``percver.Network``
    (float64 copies of the weights; ``scale`` and ``offset`` become its output map). Given the
    training ``inputs`` (N x n_in), their per-input range becomes the network's ``domain``."""
    from percver.networks import Layer, Network

    torch = require_torch("converting torch modules")
    names = {torch.nn.Tanh: "tanh", torch.nn.Sigmoid: "sigmoid", torch.nn.ReLU: "relu"}
    layers, pending = [], None
    for part in module:
        if isinstance(part, torch.nn.Linear):
            if pending is not None:
                layers.append(Layer(*pending, "identity"))
            pending = (part.weight.detach().double().numpy(), part.bias.detach().double().numpy())
        elif type(part) in names and pending is not None:
            layers.append(Layer(*pending, names[type(part)]))
            pending = None
        else:
            raise InputError(f"cannot convert {type(part).__name__} to a dense layer: use Linear, Tanh, Sigmoid, ReLU")
    if pending is not None:
        layers.append(Layer(*pending, "identity"))
    domain = None if inputs is None else list(zip(np.min(inputs, axis=0), np.max(inputs, axis=0)))
    return Network(layers, scale=scale, offset=offset, name=name, domain=domain)


def fit(torch, module, inputs, targets, loss_fn, *, epochs, batch, lr, weight_decay, seed, progress, desc):
    """Adam with a cosine schedule on standardised inputs; the standardisation is folded into
    the first layer afterwards, so the module takes the raw inputs (pose features that span a
    few hundredths are too small for a step in them to be learnt unscaled). The module ends
    in float64, so that export does not round to float32 again. With ``progress`` it first says
    about how long training will take (a few mini-batches timed), then shows a bar over all
    mini-batches with the time left."""
    inputs = np.asarray(inputs, dtype=np.float64)
    mean, scale = inputs.mean(axis=0), np.maximum(inputs.std(axis=0), 1e-3)
    generator = torch.Generator().manual_seed(seed)
    x = torch.as_tensor(((inputs - mean) / scale).astype(np.float32))
    y = torch.as_tensor(np.asarray(targets, dtype=np.float32))
    optimiser = torch.optim.Adam(module.parameters(), lr=lr, weight_decay=weight_decay)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, max(epochs, 1))
    batches = -(-len(x) // batch)
    bar = None
    if progress:
        from tqdm import tqdm

        seconds = _seconds_per_batch(torch, module, x, y, loss_fn, batch, lr, weight_decay)
        total = batches * epochs
        print(
            f"{desc}: about {_duration(seconds * total)} for {epochs} epochs of {batches} mini-batches (timed on {PROBE_BATCHES})",
            file=sys.stderr,
        )
        bar = tqdm(total=total, desc=desc, unit="batch")
    for epoch in range(epochs):
        order = torch.randperm(len(x), generator=generator)
        total = 0.0
        for lo in range(0, len(x), batch):
            index = order[lo : lo + batch]
            optimiser.zero_grad()
            loss = loss_fn(module(x[index]), y[index])
            loss.backward()
            optimiser.step()
            total += loss.item() * len(index)
            if bar is not None:
                bar.update(1)
        schedule.step()
        if bar is not None:
            bar.set_postfix(epoch=f"{epoch + 1}/{epochs}", loss=f"{total / len(x):.4f}")
    if bar is not None:
        bar.close()
    module.double()
    first = module[0]
    with torch.no_grad():
        weight = first.weight / torch.as_tensor(scale)
        first.bias.copy_(first.bias - weight @ torch.as_tensor(mean))
        first.weight.copy_(weight)


# Mini-batches timed before training to say how long it will take.
PROBE_BATCHES = 5


def _seconds_per_batch(torch, module, x, y, loss_fn, batch, lr, weight_decay) -> float:
    """The time of one training step (forward, backward, Adam) on a copy of the module, so the
    estimate comes before training and training itself is unchanged (same weights, same draws)."""
    probe = copy.deepcopy(module)
    optimiser = torch.optim.Adam(probe.parameters(), lr=lr, weight_decay=weight_decay)
    starts = [lo % len(x) for lo in range(0, (PROBE_BATCHES + 1) * batch, batch)]

    def step(lo):
        optimiser.zero_grad()
        loss_fn(probe(x[lo : lo + batch]), y[lo : lo + batch]).backward()
        optimiser.step()

    step(starts[0])  # the first step also sets torch up: not timed
    started = time.perf_counter()
    for lo in starts[1:]:
        step(lo)
    return (time.perf_counter() - started) / PROBE_BATCHES


def _duration(seconds: float) -> str:
    """``seconds`` as people say it: 0.4 s, 40 s, 3.5 min, 1.2 h."""
    if seconds < 10:
        return f"{seconds:.1f} s"
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.1f} h"


def session(torch, seed: int, threads: int | None) -> None:
    """Seed torch and, when asked, set its threads (small models train fastest on one)."""
    if threads:
        torch.set_num_threads(int(threads))
    torch.manual_seed(seed)
