"""Fusing consecutive network stages of a closed loop into one network.

Why: set propagation through a network keeps its approximation errors as symbols that later
layers can cancel; between two stages they are boxed into interval remainders, and a remainder
entering a 600-wide layer is multiplied by sum |W|. A perception chain (generator -> noise model
-> estimator -> controller) written as four stages therefore loses most of its precision at the
stage boundaries. Fused, the chain is one network: the signals a later stage needs from earlier
ones (the noise parameter, the velocity) ride along as identity neurons, which add no
approximation error. Float evaluation is unchanged (the same affine maps, reordered).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from percver.networks import Layer, Network


@dataclass
class Fused:
    """One stage of the compiled loop: ``component`` reads environment indices ``inputs`` and
    appends ``outputs`` (signal names, one per output value) to the environment."""

    component: object
    inputs: list
    outputs: list


def fuse(env_names: list, stage_inputs: list, stages: list, needed_after: set) -> tuple[list, list]:
    """Stages with runs of consecutive networks fused, and the environment names they produce.

    ``env_names`` is the original environment (states, then every stage's outputs, in order);
    ``stage_inputs`` the original input indices of each stage; ``needed_after`` the names the plant
    reads. Returns ``(fused stages, new environment names)``.
    """
    n_states = len(env_names) - sum(s.width for s in stages)
    starts, at = [], n_states
    for s in stages:
        starts.append(at)
        at += s.width
    # Names read by anything after stage k (later stages, the plant).
    reads_after = [set(needed_after) for _ in stages]
    for k in range(len(stages) - 2, -1, -1):
        reads_after[k] = reads_after[k + 1] | {env_names[i] for i in stage_inputs[k + 1]}
    out: list = []
    env = list(env_names[:n_states])
    k = 0
    while k < len(stages):
        end = k
        while end + 1 < len(stages) and stages[k].is_network and stages[end + 1].is_network:
            end += 1
        if end == k:
            names = env_names[starts[k] : starts[k] + stages[k].width]
            out.append(Fused(stages[k].component, [env.index(env_names[i]) for i in stage_inputs[k]], names))
            env += names
        else:
            net, inputs, outputs = _fuse_run(env_names, stage_inputs, stages, starts, k, end, reads_after[end])
            out.append(Fused(net, [env.index(n) for n in inputs], outputs))
            env += outputs
        k = end + 1
    return out, env


def _fuse_run(env_names, stage_inputs, stages, starts, first, last, needed_after):
    """One network for stages first..last: inputs are the signals the run reads from before it,
    outputs the run's signals read after it (the last stage's outputs always)."""
    produced = set()
    for k in range(first, last + 1):
        produced |= set(env_names[starts[k] : starts[k] + stages[k].width])
    inputs = []
    for k in range(first, last + 1):
        for i in stage_inputs[k]:
            name = env_names[i]
            if name not in produced and name not in inputs:
                inputs.append(name)
    carried = list(inputs)  # the signals the fused network holds at this point, in order
    layers: list = []
    pending_map = None  # output map of the previous stage, folded into the next first layer
    for k in range(first, last + 1):
        net = stages[k].component
        own = env_names[starts[k] : starts[k] + stages[k].width]
        later = set(needed_after)
        for j in range(k + 1, last + 1):
            later |= {env_names[i] for i in stage_inputs[j]}
        keep = [n for n in carried if n in later]  # values this stage hands on unchanged
        at = {n: c for c, n in enumerate(carried)}
        select = np.zeros((net.n_in, len(carried)))
        for row, i in enumerate(stage_inputs[k]):
            select[row, at[env_names[i]]] = 1.0
        scale, offset = pending_map if pending_map is not None else (np.ones(len(carried)), np.zeros(len(carried)))
        for depth, layer in enumerate(net.layers):
            if depth == 0:
                # The carried values are scale * h + offset: fold that and the input selection in.
                through = np.zeros((len(keep), len(carried)))
                for row, name in enumerate(keep):
                    through[row, at[name]] = scale[at[name]]
                weight = np.vstack([(layer.weight @ select) * scale, through])
                bias = np.concatenate([layer.bias + layer.weight @ (select @ offset), [offset[at[n]] for n in keep]])
            else:
                weight = np.zeros((layer.n_out + len(keep), layer.n_in + len(keep)))
                weight[: layer.n_out, : layer.n_in] = layer.weight
                weight[layer.n_out :, layer.n_in :] = np.eye(len(keep))
                bias = np.concatenate([layer.bias, np.zeros(len(keep))])
            layers.append(Layer(weight, bias, tuple(layer.activations) + ("identity",) * len(keep)))
        n_own = len(own)
        own_scale = np.ones(n_own) if net.scale is None else np.asarray(net.scale, float)
        own_offset = np.zeros(n_own) if net.offset is None else np.asarray(net.offset, float)
        pending_map = (np.concatenate([own_scale, np.ones(len(keep))]), np.concatenate([own_offset, np.zeros(len(keep))]))
        carried = list(own) + keep
    outputs = [n for n in carried if n in needed_after or n in env_names[starts[last] : starts[last] + stages[last].width]]
    if outputs != carried:
        # Drop carried values nobody reads after the run: a final selection folded into the output map is
        # not possible (it removes rows), so select them in one identity layer.
        pick = np.zeros((len(outputs), len(carried)))
        for row, name in enumerate(outputs):
            pick[row, carried.index(name)] = 1.0
        scale, offset = pending_map
        layers.append(Layer(pick * scale, pick @ offset, "identity"))
        pending_map = None
    scale, offset = pending_map if pending_map is not None else (None, None)
    names = [stages[k].name for k in range(first, last + 1)]
    return Network(layers, scale=scale, offset=offset, name=" -> ".join(names)), inputs, outputs
