"""numpy 1.26 (Blender 5.0's) and numpy 2 (Blender 5.1 and 5.2 LTS: 2.5 with bpy 5.2.3): the
one place where the add-on meets a difference between them.

Blender ships its own numpy and the add-on never bundles one, so the same code runs on both:
  trapezoid   the trapezoid rule: numpy 2 renamed np.trapz to np.trapezoid (2.0) and then
              removed np.trapz; numpy 1.26 has only np.trapz.
Every other numpy call the add-on makes behaves alike on both (tests/core/test_np_compat.py
keeps the names numpy 2 removed out of the project's code). Pure numpy: no bpy.
"""

from __future__ import annotations

import numpy as np

#: integral of y over x (or over steps dx) by the trapezoid rule, along `axis`
trapezoid = getattr(np, "trapezoid", None) or np.trapz

__all__ = ["trapezoid"]
