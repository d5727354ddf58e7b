"""Flow* export in the Verisig 1.0 style, read back by percver's own Flow* parser and run by its
own engine (Taylor models through the jumps): the reach sets must enclose float samples of the
network (numpy forward pass) or of the closed loop, and agree with
``net.bounds(box, method="verisig")``. Automata wider than a Taylor model's space run neuron
by neuron (``taylor::coupling``)."""

from pathlib import Path

import numpy as np
import pytest

import percver as pv
from percver.networks import Layer, Network

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
SAMPLES = 4000


def load(name: str) -> pv.Network:
    return pv.load_network(DATA / name)


def around(network: pv.Network, half_width: float, seed: int) -> list:
    centre = np.random.default_rng(seed).uniform(-0.5, 0.5, network.n_in)
    return list(zip(centre - half_width, centre + half_width))


def samples(box: list, seed: int = 0) -> np.ndarray:
    lo, hi = np.array(box).T
    return np.random.default_rng(seed).uniform(lo, hi, (SAMPLES, len(box)))


def small(activations: list, seed: int, n_in: int = 2, width: int = 6, scale=None) -> pv.Network:
    """A random network of ``width`` neurons a layer and one output (an identity output layer
    when the last activation is 'identity'), optionally with an output map."""
    rng = np.random.default_rng(seed)
    layers, fan_in = [], n_in
    for k, act in enumerate(activations):
        out = 1 if k == len(activations) - 1 else width
        layers.append(Layer(rng.normal(size=(out, fan_in)) / np.sqrt(fan_in), 0.1 * rng.normal(size=out), act))
        fan_in = out
    return Network(layers) if scale is None else Network(layers, scale=[scale[0]], offset=[scale[1]])


def run_exported(path: Path, jumps: str = "taylor"):
    """The file's reach set with the file's settings (adaptive steps from 1e-6 to 0.05)."""
    model = pv.formats.load_flowstar(str(path))
    assert isinstance(model, pv.formats.FlowstarHybrid)
    return model.run(jumps=jumps)


def exported_outputs(network: pv.Network, box: list, tmp_path: Path) -> list:
    final = run_exported(pv.formats.to_flowstar(network, tmp_path / "network.model", box)).reach_box("_out")
    return [final[f"y{k + 1}"] for k in range(network.n_out)]


MC_CONTROLLER = "verisig2_suite/mountain_car_small/sig16x16.yml"


def check_against_methods(network: pv.Network, box: list, exported: list) -> None:
    """Sound for samples; no wider than interval propagation (which boxes every layer) up to the
    ODE remainders; about the size of the Verisig method's bounds (Taylor models through the
    same ODEs, as the export's run carries them through the jumps)."""
    y = network(samples(box))
    verisig = network.bounds(box, method="verisig")
    interval = network.bounds(box, method="interval")
    for k, ((lo, hi), (v_lo, v_hi), (i_lo, i_hi)) in enumerate(zip(exported, verisig, interval)):
        assert lo <= y[:, k].min() and y[:, k].max() <= hi, (k, (lo, hi), y[:, k].min(), y[:, k].max())
        assert hi - lo <= 1.05 * (i_hi - i_lo) + 5e-4, (k, (lo, hi), (i_lo, i_hi))
        assert max(lo, v_lo) <= min(hi, v_hi) and hi - lo <= 2.0 * (v_hi - v_lo) + 1e-3, (k, (lo, hi), (v_lo, v_hi))


@pytest.mark.slow
def test_a_wide_export_encloses_the_network(tmp_path):
    # Two sigmoid layers of 20: 44 variables, more than one Taylor model's space holds (31); the
    # run integrates neuron by neuron. Boxing at the jumps gives fresh symbols to the 14 widest
    # variables only (the rest are intervals): sound, and no tighter than the models.
    network = small(["sigmoid", "sigmoid", "tanh"], seed=8, width=20)
    box = around(network, 0.02, seed=3)
    path = pv.formats.to_flowstar(network, tmp_path / "wide.model", box)
    assert len(pv.formats.load_flowstar(str(path)).variables) == 44
    taylor = run_exported(path).reach_box("_out")["y1"]
    check_against_methods(network, box, [taylor])
    boxed = run_exported(path, jumps="box").reach_box("_out")["y1"]
    y = network(samples(box))[:, 0]
    assert boxed[0] <= y.min() and y.max() <= boxed[1], (boxed, y.min(), y.max())
    assert boxed[1] - boxed[0] > 2 * (taylor[1] - taylor[0]), (boxed, taylor)


def test_a_wide_export_boxed_at_the_jumps_keeps_interval_width(tmp_path):
    # Two tanh layers of 30 (64 variables) over a box where the second layer's pre-activations
    # are up to 5.3 wide: one flowpipe per neuron there fails or ends far wider than tanh's
    # range. Boxing at the jumps, each neuron flows from its own box in a space of its own,
    # halved where needed: every sample inside, and about interval propagation's width (the
    # same boxes, each activation integrated as its ODE).
    network = small(["tanh", "tanh", "identity"], seed=5, width=30)
    box = around(network, 0.5, seed=2)
    run = run_exported(pv.formats.to_flowstar(network, tmp_path / "wide.model", box), jumps="box")
    assert run.failure is None, run.failure
    lo, hi = run.reach_box("_out")["y1"]
    y = network(samples(box, seed=4))[:, 0]
    assert lo <= y.min() and y.max() <= hi, ((lo, hi), y.min(), y.max())
    ((i_lo, i_hi),) = network.bounds(box, method="interval")
    assert hi - lo <= 1.1 * (i_hi - i_lo), ((lo, hi), (i_lo, i_hi))


@pytest.mark.parametrize(
    "activations, scale, half_width",
    [
        (["sigmoid", "sigmoid", "tanh"], None, 1e-6),  # sigmoid layers, tanh output
        (["sigmoid", "sigmoid", "tanh"], None, 0.02),
        (["tanh", "tanh", "tanh"], None, 0.05),
        (["sigmoid", "sigmoid", "sigmoid"], (8.0, -4.0), 0.02),  # output map 8 y - 4
        (["tanh", "tanh", "identity"], None, 0.05),  # affine output layer: a mode of zero dwell
    ],
)
def test_exported_network_encloses_samples_and_agrees_with_verisig(tmp_path, activations, scale, half_width):
    network = small(activations, seed=len(activations) + int(1e3 * half_width), scale=scale)
    box = around(network, half_width, seed=3)
    check_against_methods(network, box, exported_outputs(network, box, tmp_path))


def test_chain_with_passthrough_and_output_maps(tmp_path):
    # Identity neurons (the carried input) sit in sigmoid/tanh layers: set by the resets directly.
    first, second = small(["tanh", "tanh"], seed=1, width=4), small(["sigmoid", "sigmoid"], seed=2, width=4, scale=(8.0, -4.0))
    network = pv.chain(first.passthrough(["x2"]), second)
    box = [(0.1, 0.1002), (-0.3, -0.2998), (0.25, 0.2502)]
    check_against_methods(network, box, exported_outputs(network, box, tmp_path))


def test_the_file_is_verisig_style(tmp_path):
    network = load(MC_CONTROLLER)
    text = pv.formats.to_flowstar(network, tmp_path / "mc.model", [(-0.5, -0.49), (0.0, 0.0)]).read_text()
    assert text.startswith("hybrid reachability")
    assert "_z1' = _a1 * _z1 * (1 - _z1)" in text  # sigmoid layers
    assert "_z1' = _a1 * (1 - _z1 * _z1)" in text  # the tanh output layer
    model = pv.formats.load_flowstar(str(tmp_path / "mc.model"))
    assert list(model.modes) == ["_start", "layer1", "layer2", "layer3", "_out"]
    assert [(j.source, j.target) for j in model.jumps] == [
        ("_start", "layer1"),
        ("layer1", "layer2"),
        ("layer2", "layer3"),
        ("layer3", "_out"),
    ]


def mountain_car_plant():
    p, v, u = pv.variables("p v u")
    v_next = pv.clip(v + 0.0015 * u - 0.0025 * pv.cos(3 * p), -0.07, 0.07)
    return pv.Discrete({p: p + v_next, v: v_next}, inputs=[u])


def simulate(network: pv.Network, plant: pv.Discrete, x: np.ndarray, steps: int) -> np.ndarray:
    """The closed loop in floats, the plant through its own expressions."""
    for _ in range(steps):
        u = network(x[:, [plant.states.index(n) for n in network.input_names]])
        values = {**dict(zip(plant.states, x.T)), **dict(zip(plant.inputs, u.T))}
        x = pv.evaluate(plant.update, values)
    return x


def test_closed_loop_with_a_piecewise_plant(tmp_path):
    # Mountain Car with the Verisig 2.0 suite's controller: cos via the _reset_plant mode, the
    # velocity clip as one jump per branch combination.
    network = small(["sigmoid", "sigmoid", "tanh"], seed=5, width=4).with_input_names(["p", "v"])
    plant, steps = mountain_car_plant(), 6
    init = {"p": (-0.52, -0.518), "v": (0.0, 0.0)}
    path = pv.formats.to_flowstar(network, tmp_path / "loop.model", init, plant=plant, steps=steps)
    text = path.read_text()
    assert "_reset_plant" in text and text.count("_reset_plant -> _start") == 3
    final = run_exported(path).reach_box("_done")
    x = simulate(network, plant, samples([init["p"], init["v"]]), steps)
    for k, name in enumerate(plant.states):
        lo, hi = final[name]
        assert lo <= x[:, k].min() and x[:, k].max() <= hi, (name, (lo, hi), x[:, k].min(), x[:, k].max())
        assert hi - lo < 2.0 * (x[:, k].max() - x[:, k].min()) + 1e-4, (name, hi - lo)


def test_where_and_abs_become_branches(tmp_path):
    x, y, u = pv.variables("x y u")
    plant = pv.Discrete({x: pv.where(x >= 0, 0.5 * x, -x) + 0.1 * u, y: pv.abs_(y - x) + pv.exp(u) * 0.01}, inputs=[u])
    network = small(["tanh", "identity"], seed=6, width=3).with_input_names(["x", "y"])
    init = {"x": (-0.02, 0.03), "y": (0.2, 0.21)}
    path = pv.formats.to_flowstar(network, tmp_path / "branches.model", init, plant=plant, steps=3)
    final = run_exported(path).reach_box("_done")
    points = simulate(network, plant, samples([init["x"], init["y"]], seed=3), 3)
    for k, name in enumerate(plant.states):
        assert final[name][0] <= points[:, k].min() and points[:, k].max() <= final[name][1], name


class TestBadInput:
    def test_relu_networks_are_refused(self, tmp_path):
        with pytest.raises(pv.InputError, match=r"layer 1: \['relu'\] neurons have no Verisig ODE"):
            pv.formats.to_flowstar(load("onnx/nn_1_relu.onnx"), tmp_path / "x.model", [(0, 1), (0, 1)])

    def test_plant_mismatches(self, tmp_path):
        network = load(MC_CONTROLLER)
        with pytest.raises(pv.InputError, match=r"reads \['in0', 'in1'\], which are not states of the plant"):
            pv.formats.to_flowstar(network, tmp_path / "x.model", {"p": (0, 0), "v": (0, 0)}, plant=mountain_car_plant())
        p, v = pv.variables("p v")
        with pytest.raises(pv.InputError, match="1 outputs but the plant has 0 inputs"):
            pv.formats.to_flowstar(
                network.with_input_names(["p", "v"]), tmp_path / "x.model", {"p": (0, 0), "v": (0, 0)}, plant=pv.Discrete({p: p, v: v})
            )
        u = pv.variables("u")
        with pytest.raises(pv.InputError, match=r"Flow\* has no sigmoid\(\)"):
            pv.formats.to_flowstar(
                network.with_input_names(["p", "v"]),
                tmp_path / "x.model",
                {"p": (0, 0), "v": (0, 0)},
                plant=pv.Discrete({p: p + pv.sigmoid(u), v: v}, inputs=[u]),
            )

    def test_bad_boxes_and_names(self, tmp_path):
        network = load(MC_CONTROLLER)
        with pytest.raises(pv.InputError, match=r"init \(one interval per network input: in0, in1\): bound of 'in0' is NaN"):
            pv.formats.to_flowstar(network, tmp_path / "x.model", [(float("nan"), 1.0), (0, 1)])
        with pytest.raises(pv.InputError, match="box has 2 names but 1 intervals"):
            pv.formats.to_flowstar(network, tmp_path / "x.model", [(0, 1)])
        with pytest.raises(pv.InputError, match="'clock' cannot be a Flow. variable"):
            pv.formats.to_flowstar(network.with_input_names(["clock", "v"]), tmp_path / "x.model", [(0, 1), (0, 1)])

    def test_verisig_2_models_point_to_load_verisig(self):
        with pytest.raises(pv.ParseError, match=r"MC_small_sig_verisig.model, line \d+, column \d+: mode DNNm1 .*load_verisig"):
            pv.formats.load_flowstar(str(DATA / "verisig2_suite" / "mountain_car_small" / "MC_small_sig_verisig.model"))
