"""Network files: the reader or writer for a network chosen by the file's suffix."""

from __future__ import annotations

from pathlib import Path

from percver.errors import MissingFileError, NetworkFormatError
from percver.networks import Network


# The codecs load on first use: ``import onnx`` alone takes a third of ``import percver``.
def _readers() -> dict:
    from percver.formats.mat import read_mat
    from percver.formats.nnet import read_nnet
    from percver.formats.onnx import read_onnx
    from percver.formats.verisig_yaml import read_verisig_yaml

    return {".onnx": read_onnx, ".yml": read_verisig_yaml, ".yaml": read_verisig_yaml, ".nnet": read_nnet, ".mat": read_mat}


def _writers() -> dict:
    from percver.formats.onnx import write_onnx
    from percver.formats.verisig_yaml import write_verisig_yaml

    return {".onnx": write_onnx, ".yml": write_verisig_yaml, ".yaml": write_verisig_yaml}


def load_network(path, *, domain=None) -> Network:
    """Read a network from ``.onnx``, a Verisig ``.yml``/``.yaml``, an NNet ``.nnet`` or a MATLAB
    ``.mat`` file (W, b and act_fcns, the NNV/CORA/JuliaReach layout).

    ``domain`` (see :attr:`Network.domain`) overrides the input domain the file records (percver's
    ONNX exports record it; the other formats cannot).
    """
    path = Path(path)
    if not path.is_file():
        raise MissingFileError(f"network file not found: {path}")
    reader = _readers().get(path.suffix.lower())
    if reader is None:
        raise NetworkFormatError(
            f"{path}: unknown network file type {path.suffix!r}; percver reads .onnx, Verisig .yml/.yaml, .nnet and .mat"
        )
    network = reader(path)
    return network if domain is None else network.with_domain(domain)


def save_network(network: Network, path) -> Path:
    """Write ``network`` to ``path`` in the format its suffix names, for :func:`load_network` and
    other tools: ``.onnx`` a float64 ONNX graph (one Gemm per layer, the input domain as metadata)
    that onnxruntime runs; ``.yml``/``.yaml`` a Verisig network file, where an output map becomes
    an extra linear layer (the format has none)."""
    path = Path(path)
    writer = _writers().get(path.suffix.lower())
    if writer is None:
        raise NetworkFormatError(f"{path}: percver writes networks as .onnx or Verisig .yml/.yaml, not {path.suffix!r}")
    writer(network, path)
    return path
