"""Feed-forward networks: the one representation shared by file formats, float evaluation and the Rust core.

A :class:`Network` is a sequence of dense layers ``h <- act(W h + b)`` followed by an optional
elementwise output map ``y <- scale * h + offset``. Every reader (ONNX, Verisig ``.yml``) folds its
file into this form, so float evaluation here and set evaluation in ``percver._core`` see exactly the
same weights. Arrays are float64, C-contiguous and read-only: a network is a value, safe to share.

An activation is one name for the whole layer or one name per neuron. Per-neuron activations exist
for :meth:`Network.passthrough`: a stage of a perception chain that must carry inputs of later
stages (a noise parameter, the velocity) past itself gets identity neurons for them, so that
:func:`chain` can still compose everything into one network and :meth:`Network.bounds` propagates
Taylor models through the whole chain without boxing in between.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.special import expit

from percver import _core
from percver.errors import InputError, NetworkFormatError

ACTIVATIONS = ("sigmoid", "tanh", "relu", "identity")


ACTIVATION_FUNCTIONS = {
    # scipy's expit: no overflow, full relative accuracy on both tails, and one pass over the
    # array (falsification spends most of its time in the activations of wide layers)
    "sigmoid": expit,
    "tanh": np.tanh,
    "relu": lambda z: np.maximum(z, 0.0),
    "identity": lambda z: z,
}


@dataclass(frozen=True, eq=False)
class Layer:
    """One dense layer ``activation(weight @ h + bias)``; ``weight`` has shape (n_out, n_in).

    ``activation`` is one name for every neuron, or a tuple with one name per neuron.
    """

    weight: np.ndarray
    bias: np.ndarray
    activation: str | tuple[str, ...] = "identity"

    @property
    def n_in(self) -> int:
        return self.weight.shape[1]

    @property
    def n_out(self) -> int:
        return self.weight.shape[0]

    @property
    def activations(self) -> tuple[str, ...]:
        """The activation of every neuron."""
        if isinstance(self.activation, str):
            return (self.activation,) * self.n_out
        return self.activation

    def uniform_activation(self, purpose: str) -> str:
        """The layer's single activation; a per-neuron mix cannot be written in ``purpose``."""
        if isinstance(self.activation, str):
            return self.activation
        raise NetworkFormatError(
            f"{purpose} has one activation per layer, but this layer mixes {sorted(set(self.activation))} "
            "per neuron (a passthrough); write the networks of the chain separately"
        )

    def _apply(self, z: np.ndarray) -> np.ndarray:
        if isinstance(self.activation, str):
            return ACTIVATION_FUNCTIONS[self.activation](z)
        out = np.empty_like(z)
        names = np.array(self.activation)
        for name in set(self.activation):
            columns = names == name
            out[..., columns] = ACTIVATION_FUNCTIONS[name](z[..., columns])
        return out


def _finite_array(value, ndim: int, label: str) -> np.ndarray:
    try:
        array = np.array(value, dtype=np.float64, order="C")  # a copy: the network must not alias caller data
    except (TypeError, ValueError) as error:
        raise NetworkFormatError(f"{label} is not a numeric array ({error})") from None
    if array.ndim != ndim or array.size == 0:
        raise NetworkFormatError(f"{label} must be a non-empty {ndim}-D array, got shape {array.shape}")
    bad = np.argwhere(~np.isfinite(array))
    if bad.size:
        index = tuple(int(i) for i in bad[0])
        raise NetworkFormatError(f"{label} has the non-finite value {array[index]} at index {index} ({len(bad)} non-finite in all)")
    array.setflags(write=False)
    return array


def _checked_layer(layer, index: int, where: str, n_prev: int | None) -> Layer:
    label = f"{where}layer {index}"
    if not isinstance(layer, Layer):
        try:
            layer = Layer(*layer)
        except TypeError:
            raise NetworkFormatError(f"{label} must be a Layer or a (weight, bias, activation) tuple") from None
    weight = _finite_array(layer.weight, 2, f"{label} weight")
    bias = _finite_array(layer.bias, 1, f"{label} bias")
    if bias.shape[0] != weight.shape[0]:
        raise NetworkFormatError(
            f"{label}: bias has {bias.shape[0]} entries but weight has {weight.shape[0]} rows (weight is n_out x n_in)"
        )
    activation = _checked_activation(layer.activation, label, weight.shape[0])
    if n_prev is not None and weight.shape[1] != n_prev:
        raise NetworkFormatError(f"{label}: weight has {weight.shape[1]} columns but layer {index - 1} has {n_prev} outputs")
    return Layer(weight, bias, activation)


def _checked_activation(value, label: str, n_out: int) -> str | tuple[str, ...]:
    names = [value] if isinstance(value, str) else list(value) if isinstance(value, (list, tuple)) else [value]
    lowered = [name.lower() if isinstance(name, str) else name for name in names]
    for name in lowered:
        if name not in ACTIVATIONS:
            raise NetworkFormatError(f"{label}: unknown activation {name!r}; expected one of {ACTIVATIONS}")
    if isinstance(value, str):
        return lowered[0]
    if len(lowered) != n_out:
        raise NetworkFormatError(f"{label}: {len(lowered)} activations for {n_out} neurons; give one name, or one per neuron")
    return lowered[0] if len(set(lowered)) == 1 else tuple(lowered)


def _checked_output_map(value, field: str, n_out: int, where: str) -> np.ndarray | None:
    if value is None:
        return None
    label = f"{where}output {field}"
    try:
        value = np.broadcast_to(np.asarray(value, dtype=np.float64), (n_out,))
    except (TypeError, ValueError) as error:
        raise NetworkFormatError(f"{label} must be a number or have one entry per output ({n_out}): {error}") from None
    return _finite_array(value, 1, label)


class Network:
    """A feed-forward network of dense layers with an optional output map ``scale * h + offset``.

    ``layers`` holds :class:`Layer` objects or ``(weight, bias, activation)`` tuples; activations are
    ``"sigmoid"``, ``"tanh"``, ``"relu"`` or ``"identity"`` (one per layer, or a tuple with one per
    neuron). ``scale`` and ``offset`` are numbers or one value per output (``None``: not applied).
    ``input_names`` name the inputs for :meth:`bounds` (default ``in0``, ``in1``, ...). ``domain``
    is the input range the network was trained on (see :attr:`domain`). Layers are numbered from 1
    in error messages, as in Verisig files.
    """

    def __init__(self, layers, *, scale=None, offset=None, name: str | None = None, source=None, input_names=None, domain=None):
        self._source = Path(source) if source is not None else None
        where = f"{self._source}: " if self._source is not None else ""
        checked: list[Layer] = []
        for index, layer in enumerate(layers, start=1):
            checked.append(_checked_layer(layer, index, where, checked[-1].n_out if checked else None))
        if not checked:
            raise NetworkFormatError(f"{where}a network needs at least one layer")
        self._layers = tuple(checked)
        self._scale = _checked_output_map(scale, "scale", checked[-1].n_out, where)
        self._offset = _checked_output_map(offset, "offset", checked[-1].n_out, where)
        self._name = name if name is not None else (self._source.stem if self._source is not None else "network")
        self._input_names = None if input_names is None else _checked_names(input_names, checked[0].n_in, self._name)
        self._domain = None if domain is None else self._checked_domain(domain)
        self._rust = None

    @property
    def layers(self) -> tuple[Layer, ...]:
        return self._layers

    @property
    def n_in(self) -> int:
        return self._layers[0].n_in

    @property
    def n_out(self) -> int:
        return self._layers[-1].n_out

    @property
    def input_names(self) -> tuple[str, ...]:
        """Names of the inputs, as :meth:`bounds` accepts them in a box dict."""
        return self._input_names or tuple(f"in{i}" for i in range(self.n_in))

    @property
    def scale(self) -> np.ndarray | None:
        """Per-output factor of the output map, or ``None``."""
        return self._scale

    @property
    def offset(self) -> np.ndarray | None:
        """Per-output offset of the output map (added after ``scale``), or ``None``."""
        return self._offset

    @property
    def name(self) -> str:
        return self._name

    @property
    def domain(self) -> tuple[tuple[float, float], ...] | None:
        """The input range the network was trained on: one ``(lo, hi)`` per input (``-inf``/``inf``
        where an input is unbounded), or ``None`` when unknown.

        Outside it the network's outputs are extrapolation, so a proof over such inputs is about a
        function nobody checked; :func:`percver.verify` warns when a set leaves it. percver's ONNX
        exports carry it in their metadata; :func:`percver.formats.load_network` (``domain=``) and
        :meth:`with_domain` set it for other files.
        """
        return self._domain

    def with_domain(self, domain) -> Network:
        """The same network with input domain ``domain``: a dict ``{input name: (lo, hi)}`` (inputs
        not named are unbounded), a list of one ``(lo, hi)`` per input, or ``None`` (unknown)."""
        return Network(
            self._layers,
            scale=self._scale,
            offset=self._offset,
            name=self._name,
            source=self._source,
            input_names=self._input_names,
            domain=domain,
        )

    def _checked_domain(self, domain) -> tuple[tuple[float, float], ...]:
        where = f"{self._source}: " if self._source is not None else ""
        names = self.input_names
        if isinstance(domain, dict):
            unknown = [k for k in domain if k not in names]
            if unknown:
                raise InputError(
                    f"{where}network {self._name!r}: domain names {unknown[:8]}, not among its inputs ({', '.join(names[:8])} ...)"
                )
            domain = [domain.get(n, (-np.inf, np.inf)) for n in names]
        try:
            pairs = [(float(lo), float(hi)) for lo, hi in domain]
        except (TypeError, ValueError):
            raise InputError(f"{where}network {self._name!r}: a domain is a dict or list of (lo, hi) pairs, got {domain!r:.80}") from None
        if len(pairs) != self.n_in:
            raise InputError(f"{where}network {self._name!r} has {self.n_in} inputs but its domain has {len(pairs)} intervals")
        for name, (lo, hi) in zip(names, pairs):
            if not lo <= hi or lo == np.inf or hi == -np.inf:  # NaN fails lo <= hi
                raise InputError(f"{where}network {self._name!r}: domain of input {name!r} is [{lo}, {hi}]; give lo <= hi, no NaN")
        return tuple(pairs)

    @property
    def source(self) -> Path | None:
        """The file the network was read from, if any."""
        return self._source

    def __call__(self, batch) -> np.ndarray:
        """Float evaluation: one sample of shape (n_in,) or a batch of shape (k, n_in)."""
        try:
            x = np.asarray(batch, dtype=np.float64)
        except (TypeError, ValueError) as error:
            raise InputError(f"network {self._name!r}: input is not numeric ({error})") from None
        if x.ndim not in (1, 2) or x.shape[-1] != self.n_in:
            raise InputError(
                f"network {self._name!r} takes {self.n_in} inputs per sample: pass shape ({self.n_in},) "
                f"or (batch, {self.n_in}), got shape {x.shape}"
            )
        h = x
        for layer in self._layers:
            h = layer._apply(h @ layer.weight.T + layer.bias)
        if self._scale is not None:
            h = h * self._scale
        if self._offset is not None:
            h = h + self._offset
        return h

    def passthrough(self, extra) -> Network:
        """This network with ``extra`` more inputs carried unchanged to ``extra`` more outputs.

        ``extra`` is a count or a list of names for the new inputs. The new inputs come after the
        network's own and reach the end of the outputs through identity neurons in every layer, so
        a stage of a chain can hand a later stage what it does not use itself::

            pv.chain(generator.passthrough(["delta", "v"]),     # (p, delta, v) -> (image, delta, v)
                     contraster.passthrough(["v"]),             # (image, delta, v) -> (noisy, v)
                     estimator.passthrough(["v"]),              # (noisy, v) -> (p_hat, v)
                     controller)                                # (p_hat, v) -> u

        Bounds stay exact for the carried values (identity rows add no approximation error).
        """
        if isinstance(extra, int) and not isinstance(extra, bool):
            count, names = extra, [f"in{self.n_in + i}" for i in range(extra)]
        else:
            names = [str(n) for n in extra]
            count = len(names)
        if count < 1:
            raise InputError(f"passthrough needs at least one extra input, got {extra!r}")
        layers = []
        for layer in self._layers:
            weight = np.zeros((layer.n_out + count, layer.n_in + count))
            weight[: layer.n_out, : layer.n_in] = layer.weight
            weight[layer.n_out :, layer.n_in :] = np.eye(count)
            bias = np.concatenate([layer.bias, np.zeros(count)])
            layers.append(Layer(weight, bias, layer.activations + ("identity",) * count))
        scale = None if self._scale is None else np.concatenate([self._scale, np.ones(count)])
        offset = None if self._offset is None else np.concatenate([self._offset, np.zeros(count)])
        domain = None if self._domain is None else [*self._domain, *[(-np.inf, np.inf)] * count]
        return Network(
            layers,
            scale=scale,
            offset=offset,
            name=f"{self._name}+passthrough",
            input_names=[*self.input_names, *names],
            domain=domain,
        )

    def with_input_names(self, names) -> Network:
        """The same network with its inputs named ``names`` (for box dicts in :meth:`bounds`)."""
        return Network(
            self._layers,
            scale=self._scale,
            offset=self._offset,
            name=self._name,
            source=self._source,
            input_names=names,
            domain=self._domain,
        )

    def _core(self):
        if self._rust is None:
            self._rust = _core.Network(
                [(layer.weight, layer.bias, list(layer.activations)) for layer in self._layers],
                None if self._scale is None else self._scale.tolist(),
                None if self._offset is None else self._offset.tolist(),
            )
        return self._rust

    def _box(self, box) -> list[tuple[float, float]]:
        names = self.input_names
        if isinstance(box, dict):
            unknown = [k for k in box if k not in names]
            missing = [n for n in names if n not in box]
            if unknown or missing:
                shown = ", ".join(names) if len(names) <= 8 else f"{names[0]} ... {names[-1]}"
                raise InputError(
                    f"network {self._name!r}: box names {unknown or 'no unknown inputs'} not among its inputs "
                    f"({shown}); missing: {missing[:8] or 'none'}{' ...' if len(missing) > 8 else ''}"
                )
            box = [box[n] for n in names]
        try:
            pairs = [(float(lo), float(hi)) for lo, hi in box]
        except (TypeError, ValueError):
            raise InputError(f"network {self._name!r}: a box is a dict or list of (lo, hi) pairs") from None
        if len(pairs) != self.n_in:
            raise InputError(f"network {self._name!r} takes {self.n_in} inputs, the box has {len(pairs)} intervals")
        return pairs

    def _settings(self, order, symbolic, max_vars, pieces, back_substitution=True, alpha_steps=0) -> dict:
        splits = []
        for name, count in (pieces or {}).items():
            if name not in self.input_names:
                raise InputError(f"network {self._name!r}: cannot split {name!r}, not an input ({', '.join(self.input_names[:8])})")
            splits.append((self.input_names.index(name), int(count)))
        return dict(
            order=order,
            symbolic=symbolic,
            max_vars=max_vars,
            splits=splits,
            back_substitution=bool(back_substitution),
            alpha_steps=int(alpha_steps),
        )

    def bounds(
        self,
        box,
        method: str = "taylor",
        order: int = 5,
        *,
        pieces=None,
        symbolic: bool = True,
        max_vars: int = 4,
        leaves: int = 1,
        back_substitution: bool = True,
        alpha_steps: int = 0,
    ):
        """Sound bounds of every output over an input box: a list of ``(lo, hi)``.

        ``box`` is a dict ``{name: (lo, hi)}`` over :attr:`input_names`, a list of ``(lo, hi)`` in
        input order, or the result of :meth:`taylor_models` of a preceding network (no boxing in
        between). ``method``: ``"taylor"`` (direct Taylor-model propagation), ``"verisig"`` (each
        sigmoid/tanh neuron integrated as Verisig's ODE; slower, a cross-check) or ``"interval"``
        (naive interval arithmetic, the baseline). ``order`` is the Taylor-model order;
        ``pieces={name: k}`` splits an input into k equal pieces (the layers before the first
        nonlinear neuron that depends on it are computed once) and returns the hull. The
        ``max_vars`` widest inputs are polynomial variables, the others enter linearly as error
        symbols; ``symbolic=False`` boxes activation errors into remainders instead of keeping them.
        ``leaves=N`` (Taylor method, boxes) refines the bounds by branch and bound on the input, up to
        N sub-boxes, halving where a bound is loosest along the input that moves it most: what a
        ReLU network's linear relaxations need on wide boxes (``bench/networks.py``).
        ``back_substitution`` tightens the ranges of ReLU neurons (and of the last layer) by
        back-substituting the layers down to the input (CROWN-style linear bounds); ``False``
        keeps the Taylor models' own ranges (to compare). ``alpha_steps`` optimises the lower slopes
        of the unstable ReLUs per bound by that many gradient steps (alpha-CROWN; each step costs
        about two back-substitutions).
        """
        settings = self._settings(order, symbolic, max_vars, pieces, back_substitution, alpha_steps)
        if not (isinstance(leaves, int) and leaves >= 1):
            raise InputError(f"leaves must be a positive integer, got {leaves!r}")
        if leaves > 1 and (method != "taylor" or isinstance(box, _core.NetworkModels)):
            raise InputError("leaves= refines the bounds over a box by the Taylor method; give a box and method='taylor'")
        if leaves > 1:
            settings["leaves"] = leaves
        if isinstance(box, _core.NetworkModels):
            if len(box) != self.n_in:
                raise InputError(f"network {self._name!r} takes {self.n_in} inputs, the models have {len(box)} outputs")
            if pieces:
                raise InputError("pieces= splits a box; Taylor-model inputs cannot be split")
            return self._core().bounds(box, method, **settings)
        return self._core().bounds(self._box(box), method, **settings)

    def taylor_models(
        self, box, method: str = "taylor", order: int = 5, *, symbolic: bool = True, max_vars: int = 4, back_substitution: bool = True
    ):
        """The outputs as Taylor models over the box's variables (``percver._core.NetworkModels``).

        Pass them as the box of the next network's :meth:`bounds` or :meth:`taylor_models` to
        propagate through several networks without boxing; ``.bounds()`` gives their ranges,
        ``.variables`` the map from inputs to polynomial variables.
        """
        settings = self._settings(order, symbolic, max_vars, None, back_substitution)
        del settings["splits"]
        if isinstance(box, _core.NetworkModels):
            if len(box) != self.n_in:
                raise InputError(f"network {self._name!r} takes {self.n_in} inputs, the models have {len(box)} outputs")
            return self._core().models(box, method, **settings)
        return self._core().models(self._box(box), method, **settings)

    def __repr__(self) -> str:
        def describe(layer: Layer) -> str:
            if isinstance(layer.activation, str):
                return f"{layer.n_out} {layer.activation}"
            return f"{layer.n_out} " + "+".join(f"{layer.activations.count(a)} {a}" for a in dict.fromkeys(layer.activation))

        parts = [str(self.n_in)] + [describe(layer) for layer in self._layers]
        if self._scale is not None or self._offset is not None:
            parts.append("scale/offset")
        return f"Network({self._name!r}: {' -> '.join(parts)})"


def _checked_names(names, n_in: int, network: str) -> tuple[str, ...]:
    names = tuple(str(n) for n in names)
    if len(names) != n_in or len(set(names)) != n_in:
        raise InputError(f"network {network!r} has {n_in} inputs: give as many distinct names, got {list(names)[:8]}")
    return names


def chain(*networks: Network) -> Network:
    """Compose networks end to end: ``chain(f, g)(x) == g(f(x))``, as one Network with all layers.

    The output map of every network but the last is folded into the first layer of the next one, so
    the result is a plain layer sequence that set evaluation can propagate without boxing in between.
    """
    if not networks:
        raise InputError("chain() needs at least one network")
    for network in networks:
        if not isinstance(network, Network):
            raise InputError(f"chain() takes Network objects, got {type(network).__name__}")
    layers = list(networks[0].layers)
    for previous, following in zip(networks, networks[1:]):
        if previous.n_out != following.n_in:
            raise InputError(f"cannot chain {previous.name!r} ({previous.n_out} outputs) into {following.name!r} ({following.n_in} inputs)")
        first, *rest = following.layers
        weight, bias = first.weight, first.bias
        if previous.offset is not None:
            bias = bias + weight @ previous.offset
        if previous.scale is not None:
            weight = weight * previous.scale
        layers += [Layer(weight, bias, first.activation), *rest]
    last = networks[-1]
    return Network(
        layers,
        scale=last.scale,
        offset=last.offset,
        name=" -> ".join(n.name for n in networks),
        input_names=networks[0]._input_names,
        domain=networks[0].domain,  # later networks' domains concern inner signals: see their own stages
    )
