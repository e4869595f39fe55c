"""Learned lenses: model files (ONNX + JSON metadata), evaluation and domain guards."""
