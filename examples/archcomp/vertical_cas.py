"""ARCH-COMP AINNCS VerticalCAS (JuliaReach models/VerticalCAS): ACAS X's vertical advisories,
nine ReLU networks, one per previous advisory, each scoring the nine advisories from the
normalised (h, h0', tau); the pilot takes the central acceleration of the new advisory (0 if it
keeps an advisory it complies with). From h in [-133, -129], tau = 25 and a fixed climb rate
h0' (one variant each), the intruder must stay out of |h| <= 100 for 10 steps (1 s each)."""

import warnings

import percver as pv
from _common import main, network
from percver.formats.nnet import NNetNormalizationWarning

VARIANTS = {"-19.5": "verified", "-22.5": "verified", "-25.5": "falsified", "-28.5": "falsified"}
G = 32.2
# Per advisory (COC, DNC, DND, DES1500, CL1500, SDES1500, SCL1500, SDES2500, SCL2500): the central
# acceleration, and the climb rates (ft/min) that comply with it as (sign, bound): sign * rate >= bound.
ACCELERATION = [0.0, -7 * G / 24, 7 * G / 24, -7 * G / 24, 7 * G / 24, -G / 3, G / 3, -G / 3, G / 3]
COMPLY = [None, (-1, 0.0), (1, 0.0), (-1, 1500.0), (1, 1500.0), (-1, 1500.0), (1, 1500.0), (-1, 2500.0), (1, 2500.0)]


def chain(index, values):
    """values[index] for an integer-valued expression ``index`` in 0..len(values)-1."""
    out = values[-1]
    for i in range(len(values) - 2, -1, -1):
        out = pv.where(index <= i + 0.5, values[i], out)
    return out


def argmax(scores):
    """The first index of the largest score, as numpy's argmax."""
    out = float(len(scores) - 1)
    for i in range(len(scores) - 2, -1, -1):
        rest = scores[i + 1]
        for s in scores[i + 2 :]:
            rest = pv.max(rest, s)
        out = pv.where(scores[i] >= rest, float(i), out)
    return out


def problem(variant: str = "-19.5"):
    h, rate, tau, adv, new = pv.variables("h rate tau adv next")
    inputs = pv.Stage([h / 16000.0, rate / 5000.0, (tau - 20.0) / 40.0], inputs=["h", "rate", "tau"], output="z")
    # The inputs are normalised as JuliaReach does (h' by 5000, not by the files' 200), so the
    # files' own normalisation stays unused, as in JuliaReach.
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NNetNormalizationWarning)
        nets = [network("VerticalCAS", f"VertCAS_noResp_pra0{i + 1}_v9_20HU_200.nnet") for i in range(9)]
    scorers = [pv.Stage(net, inputs=["z"], output=f"s{i}") for i, net in enumerate(nets)]
    scores = [chain(adv, [pv.variables(f"s{i}_{j}") for i in range(9)]) for j in range(9)]
    advise = pv.Stage([argmax(scores)], inputs=["adv"] + [f"s{i}" for i in range(9)], output="next")
    kept = []
    for i, a in enumerate(ACCELERATION):
        if COMPLY[i] is None:
            kept.append(a)
            continue
        sign, bound = COMPLY[i]
        complies = pv.where(sign * 60.0 * rate >= bound, 0.0, a)
        kept.append(pv.where(adv >= i - 0.5, pv.where(adv <= i + 0.5, complies, a), a))
    acc = chain(new, kept)
    plant = pv.Discrete({h: h - rate - 0.5 * acc, rate: rate + acc, tau: tau - 1.0, adv: new})
    loop = pv.ClosedLoop(plant, [inputs, *scorers, advise])
    r0 = float(variant)
    init = {"h": (-133.0, -129.0), "rate": (r0, r0), "tau": (25.0, 25.0), "adv": (0.0, 0.0)}
    return loop, dict(init=init, steps=10, unsafe=pv.Box({"h": (-100.0, 100.0)}), order=2, max_splits=64)


if __name__ == "__main__":
    import sys

    for variant in sys.argv[1:] or VARIANTS:
        main(problem, VARIANTS[variant], variant=variant)
