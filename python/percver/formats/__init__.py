"""Readers and writers of file formats: networks (ONNX, Verisig .yml), Flow* models, benchmarks."""
