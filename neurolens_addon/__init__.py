"""NeuroLens for Blender: real camera lenses, exact and learned."""
