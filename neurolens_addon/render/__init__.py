"""Headless renders for render farms: `python -m neurolens_addon.render SCENE.blend ...`.

See `cli.py` (the command) and docs/render-engine.md.
"""
