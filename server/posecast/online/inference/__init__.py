"""Shipped model artifacts and their ONNX Runtime sessions."""
