"""Networks carry the input domain they were trained on (``Network.domain``), ONNX files keep it in
their metadata, and ``pv.verify`` warns (``strict=True``: refuses) where a set leaves it."""

import json
import math
import warnings

import numpy as np
import onnx
import pytest
from onnx import helper

import percver as pv
from percver.cases.mountain_car import verification
from percver.errors import InputError, NetworkDomainError, NetworkFormatError
from percver.formats.onnx import DOMAIN_KEY


def _net(domain=None, n_in=2):
    rng = np.random.default_rng(0)
    layers = [(rng.normal(size=(3, n_in)), rng.normal(size=3), "tanh"), (rng.normal(size=(1, 3)), [0.0], "identity")]
    return pv.Network(layers, name="net", input_names=["a", "b"][:n_in], domain=domain)


# ------------------------------------------------------------------------------ the attribute


def test_domain_is_unknown_by_default_and_set_by_dict_or_list():
    assert _net().domain is None
    assert _net({"b": (0, 1)}).domain == ((-math.inf, math.inf), (0.0, 1.0))  # unnamed inputs are unbounded
    net = _net().with_domain([(-1, 1), (0, 2)])
    assert net.domain == ((-1.0, 1.0), (0.0, 2.0))
    assert net.with_domain(None).domain is None
    # derived networks keep it: renamed inputs, carried extras (unbounded), the first of a chain
    assert net.with_input_names(["x", "y"]).domain == net.domain
    assert net.passthrough(["c"]).domain == (*net.domain, (-math.inf, math.inf))
    assert pv.chain(net, pv.Network([(np.ones((1, 1)), [0.0], "relu")])).domain == net.domain
    # a stage's output map is folded into a new network: the domain stays
    stage = pv.Stage(net, inputs=["a", "b"], output="u", scale=2.0)
    assert stage.component.domain == net.domain


@pytest.mark.parametrize(
    ("domain", "message"),
    [
        ([(0, 1)], r"has 2 inputs but its domain has 1 intervals"),
        ([(0, 1), (2, 1)], r"domain of input 'b' is \[2.0, 1.0\]; give lo <= hi"),
        ([(0, 1), (math.nan, 1)], r"domain of input 'b' is \[nan, 1.0\]"),
        ({"c": (0, 1)}, r"domain names \['c'\], not among its inputs"),
        ([0, 1], r"a domain is a dict or list of \(lo, hi\) pairs"),
    ],
)
def test_bad_domains_are_input_errors(domain, message):
    with pytest.raises(InputError, match=message):
        _net().with_domain(domain)


# ------------------------------------------------------------------------------ ONNX metadata


def test_onnx_keeps_the_domain_and_load_network_overrides_it(tmp_path):
    net = _net([(-math.inf, 0.5), (0.0, 2.0)])
    path = tmp_path / "net.onnx"
    pv.save_network(net, path)
    stored = {p.key: p.value for p in onnx.load(str(path)).metadata_props}
    assert json.loads(stored[DOMAIN_KEY]) == [[None, 0.5], [0.0, 2.0]]  # unbounded sides are null
    assert pv.load_network(path).domain == net.domain
    assert pv.load_network(path, domain={"in1": (1, 3)}).domain == ((-math.inf, math.inf), (1.0, 3.0))
    pv.save_network(_net(), path)  # no domain: no metadata, None again
    assert pv.load_network(path).domain is None


@pytest.mark.parametrize(
    ("value", "message"),
    [
        ("[[0, 1]", r"is not JSON"),
        ("[[0, 1]]", r"must list one \[lo, hi\] per input \(2\)"),
        ('[[0, 1], [3, "x"]]', r"input 1 has \[3, x\]; give numbers lo <= hi"),
        ("[[0, 1], [3, 2]]", r"input 1 has \[3, 2\]"),
    ],
)
def test_bad_domain_metadata_names_file_and_key(tmp_path, value, message):
    path = tmp_path / "bad.onnx"
    pv.save_network(_net(), path)
    model = onnx.load(str(path))
    helper.set_model_props(model, {DOMAIN_KEY: value})
    onnx.save(model, str(path))
    with pytest.raises(NetworkFormatError, match=rf"bad.onnx: metadata 'percver.domain'.*{message}"):
        pv.load_network(path)


# ------------------------------------------------------------------------------ verify


def _loop(domain):
    """x grows by 0.1 per step under a network controller that reads x (domain on x)."""
    x, u = pv.variables("x u")
    net = pv.Network([(np.array([[0.5]]), [0.0], "tanh")], name="ctl", domain=domain)
    return pv.ClosedLoop(pv.Discrete({x: x + 0.1 + 0.01 * u}, inputs=["u"]), [pv.Stage(net, inputs=[x], output="u", name="control")])


def _verify(loop, init, **options):
    x = pv.variables("x")
    return pv.verify(loop, {"x": init}, steps=8, safe=x <= 10, split={"x": 4}, progress=False, **options)


def test_reach_sets_leaving_the_domain_warn_and_are_recorded():
    loop = _loop([(0.0, 0.5)])
    with pytest.warns(pv.DomainWarning, match=r"stage 'control' \(network 'ctl'\): x in \[.*\] at step (\d) leaves \[0, 0.5\]"):
        result = _verify(loop, (0.0, 0.2))
    assert result.verdict == "verified"  # the warning does not change the verdict
    (exit_,) = result.domain_exits
    assert (exit_["stage"], exit_["network"], exit_["input"], exit_["domain"]) == ("control", "ctl", "x", (0.0, 0.5))
    # the reach boxes are sound, so the step the check reports is no later than the first simulated run
    # outside the domain, and the recorded box holds that run's state there
    runs = loop.simulate(np.linspace(0.0, 0.2, 41)[:, None], 8)[:, :, 0]
    first_out = int(np.argmax((runs > 0.5).any(axis=0)))
    assert 1 <= exit_["step"] <= first_out
    outside = runs[:, exit_["step"]][runs[:, exit_["step"]] > 0.5]
    assert np.all((exit_["box"][0] <= outside) & (outside <= exit_["box"][1]))
    assert 1 <= exit_["cells"] <= 4
    again = pv.Result.from_json(result.to_json())
    assert again.domain_exits[0]["step"] == exit_["step"] and tuple(again.domain_exits[0]["domain"]) == (0.0, 0.5)


def test_exits_of_parts_merge_into_the_whole_sets():
    # A case that verifies its bands as parts reports one result: its exits must be those of the
    # same cells verified as one set (earliest step, hull of the boxes there, runs summed).
    from percver.verification.domains import merged_exits

    loop, x = _loop([(0.0, 0.5)]), pv.variables("x")
    spec = dict(steps=8, safe=x <= 10, progress=False)
    with pytest.warns(pv.DomainWarning):
        whole = pv.verify(loop, {"x": (0.0, 0.2)}, split={"x": 4}, **spec)
        parts = pv.verify_parts(loop, [pv.Part({"x": (0.0, 0.1)}, {"x": 2}), pv.Part({"x": (0.1, 0.2)}, {"x": 2})], **spec)
    ((one,), (two,)) = (p.domain_exits for p in parts)
    assert one["step"] > two["step"]  # the upper part leaves first: the merge must take its step and box
    (merged,) = merged_exits([one, two])
    (expected,) = whole.domain_exits
    assert merged["step"] == expected["step"] and merged["cells"] == expected["cells"]
    assert merged["box"] == pytest.approx(expected["box"], abs=0) and tuple(merged["domain"]) == (0.0, 0.5)
    assert merged_exits([two, one]) == [merged]  # order does not matter


def test_strict_makes_leaving_an_error_and_staying_inside_is_silent():
    with pytest.raises(NetworkDomainError, match=r"x in \[.*\] at step [1-9] leaves \[0, 0.5\]") as caught:
        _verify(_loop([(0.0, 0.5)]), (0.0, 0.2), strict=True)
    assert caught.value.results[0].domain_exits  # the run's results come with the error
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no warning at all
        result = _verify(_loop([(0.0, 2.0)]), (0.0, 0.2), strict=True)
    assert result.domain_exits == [] and result.verdict == "verified"
    assert _verify(_loop(None), (0.0, 0.2)).domain_exits == []  # unknown domain: nothing to check


def test_initial_set_outside_is_flagged_before_the_run():
    with pytest.raises(NetworkDomainError, match=r"x in \[-0.3, 0.2\] at step 0 \(the initial set\) leaves \[0, 0.5\]") as caught:
        _verify(_loop([(0.0, 0.5)]), (-0.3, 0.2), strict=True)
    assert caught.value.results is None  # refused before any cell ran


def test_mountain_car_contrast_outside_its_training_range_is_refused():
    # the shipped contrast model was trained on delta_c in [0.3, 2]; the demo's slice once "verified" 0.05-0.1
    loop = verification.closed_loop("contrast", "ours")
    init = verification.initial_set("contrast", (-0.5, -0.499), delta_c=(0.05, 0.1))
    with pytest.raises(NetworkDomainError, match=r"stage 'image_dc' \(network 'contrast'\): dc in \[0.05, 0.1\] at step 0"):
        pv.verify(
            loop, init, steps=150, strict=True, progress=False, **{k: v for k, v in verification.specification().items() if k != "steps"}
        )
