"""The ONNX graphs of a learned lens, built node by node from a model.json dict (float32,
opset 17), and written into a model directory: builder (nodes, shared pieces), dual
(forward-mode tangents), forward (forward.onnx, forward_jacobian.onnx), fast
(forward_fast.onnx), skip (its factored polynomial skips), fast_domain (its exact float32
domain tests) and export (`write_onnx_files`: the three files and their sha256).

Its own package, beside the trainer rather than inside it: it needs onnx and numpy, never
torch, and two users write models with it: the trainer (the models it fits) and the add-on's
tests (small random models, tests/neural/synthetic.py), which must run where torch is not
(Blender 5.2 LTS's Python 3.13). It uses neurolens_addon's core and the model-file layer of
neural (the format it writes); the add-on never imports it and it is not shipped.
"""

from .export import build_fast, build_forward, occupancy_limits, write_onnx_files

__all__ = ["build_fast", "build_forward", "occupancy_limits", "write_onnx_files"]
