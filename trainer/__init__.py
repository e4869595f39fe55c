"""NeuroLens trainer: learns a lens's imaging regression function from exact traces (torch).

Imports neurolens_addon.core; never imported by the add-on.
"""
