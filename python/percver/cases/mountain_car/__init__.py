"""Image-based Mountain Car under benign noise (paper, section 5.1 and Appendix A).

- :mod:`~percver.cases.mountain_car.dynamics`: plant, reward, property and the rows of Table 1;
- :mod:`~percver.cases.mountain_car.camera`: the canonical camera g_c (gymnasium's scene), the paper's contrast and blur;
- :mod:`~percver.cases.mountain_car.dataset`: the paper's data set D;
- :mod:`~percver.cases.mountain_car.training`: the torch models, exported to ONNX (needs torch;
  imported on first use of ``train``);
- :mod:`~percver.cases.mountain_car.networks`: the chain of networks, the authors' or ours;
- :mod:`~percver.cases.mountain_car.evaluation`: the paper's state-estimation metric, plots, summary;
- :mod:`~percver.cases.mountain_car.verification`: the closed loop and the rows of Table 1.

::

    from percver.cases import mountain_car as mc
    data = mc.generate(2000, 20)                     # the paper's D (about a minute)
    mc.train(data, "mc-networks")                    # g_c, g_ct, g_b, h_e and a controller, as ONNX
    result = mc.evaluate("mc-networks", trajectories=1000)
    print(result.table())
    res = mc.verify("contrast", p0=(-0.5, -0.49), networks="paper")   # a slice of Table 1's contrast row
"""

from percver.cases.mountain_car.camera import SHAPE, Camera, blur, camera, contrast, observe, render
from percver.cases.mountain_car.dataset import Dataset, generate
from percver.cases.mountain_car.dynamics import NOISES, ROWS, Trajectories, equations, noise_row, simulate, step
from percver.cases.mountain_car.evaluation import Evaluation, evaluate
from percver.cases.mountain_car.networks import Networks, load, paper_dir
from percver.cases.mountain_car.verification import closed_loop, verify

__all__ = [
    "Camera", "Dataset", "Evaluation", "Networks", "Trajectories", "NOISES", "ROWS", "SHAPE",
    "blur", "camera", "canonical_camera", "closed_loop", "contrast", "equations", "evaluate", "generate", "load",
    "noise_row", "observe", "paper_dir", "render", "simulate", "step", "train", "verify",
]  # fmt: skip


def train(dataset, out, **options):
    """Train the models and write them as ONNX; see :func:`percver.cases.mountain_car.training.train`."""
    from percver.cases.mountain_car.training import train as run

    return run(dataset, out, **options)


def canonical_camera():
    """The canonical camera as a validation model (``percver validate --model mc-camera``)."""
    from percver.sensors.camera import ImageModel

    cam = camera()
    return ImageModel(lambda states: cam.render(states[:, 0]), ["p"], SHAPE)
