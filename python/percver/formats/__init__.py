"""Readers and writers of file formats: networks (ONNX, Verisig .yml), Flow* models, benchmarks."""
from percver.formats.flowstar import FlowstarModel, load_flowstar
