"""Learned lenses: the model file (modelfile, schema), which rays a model accepts (domain),
the onnxruntime runtime (session, model, fastpath), the float64 reference semantics
(reference), and which model a scene uses (choice, cache)."""
