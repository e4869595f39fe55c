"""Pure-numpy optics core: prescriptions, glass, exact sequential trace, paraxial data.

Never imports bpy, onnxruntime or torch (tests enforce it).
"""
