"""The ONNX graphs of a learned lens, built node by node from a model.json dict (float32,
opset 17): builder (nodes, shared pieces), dual (forward-mode tangents), forward
(forward.onnx, forward_jacobian.onnx), fast (forward_fast.onnx), skip (its factored
polynomial skips) and fast_domain (its exact float32 domain tests). trainer.export_onnx
writes them into a model directory."""
