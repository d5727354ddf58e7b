"""Readers and writers of file formats: networks (ONNX, Verisig .yml), Flow* models, benchmarks."""

from percver.formats.flowstar import FlowstarHybrid, FlowstarModel, load_flowstar
from percver.formats.flowstar_export import to_flowstar
from percver.formats.network_files import load_network, save_network
