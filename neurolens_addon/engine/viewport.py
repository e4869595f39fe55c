"""The engine's live viewport: progressive refinement through the real lens, restarted on every
change.

A `ViewportSession` holds one FrameRenderer for the state the viewport shows, named by a key
(the lens set-up, the camera's matrix, the viewport's size, the scene's change count).
`update(key, build)` starts over when the key differs (`build(sink)` makes the renderer, as
frame_setup.build_renderer does); `step(budget_s)` renders bundles until the time budget is
spent and says whether the frame is complete; `image()` is the Combined pass so far (rows
from the bottom, as a GPU texture wants them), with the lamps' flare (engine.flare) traced
once after the first step at PREVIEW_FLARE_SAMPLES samples' worth of rays. A sample's random
numbers depend only on its pixel and index, so after S samples the viewport shows exactly what
a render of S samples at its size gives (tested; the flare is the render's at those samples).
"""

from __future__ import annotations

import time

#: the viewport's flare: traced once, with the rays of this many samples
PREVIEW_FLARE_SAMPLES = 16


class _ViewportSink:
    """FrameRenderer's sink for the viewport: the film is read directly, nothing is written."""

    def write_tile(self, tile, passes):
        pass

    def progress(self, fraction, text):
        pass

    def should_stop(self) -> bool:
        return False


class ViewportSession:
    def __init__(self):
        self.key = None
        self.renderer = None
        self._materials = None
        self._steps = None
        self.done = False
        self.restarts = 0
        self._flare = None

    def update(self, key, build) -> bool:
        """Start over with `build(sink) -> (FrameRenderer, setup, materials)` when `key`
        changed; True when it did."""
        if key == self.key and self.renderer is not None:
            return False
        self.close()
        self.renderer, _setup, self._materials = build(_ViewportSink())
        self._steps = self.renderer.steps()
        self.key = key
        self.done = False
        self._flare = None
        self.restarts += 1
        return True

    def step(self, budget_s: float = 0.05) -> bool:
        """Render bundles for about `budget_s` seconds (at least one); True once complete."""
        if self.renderer is None or self.done:
            return self.done
        end = time.perf_counter() + budget_s
        while True:
            try:
                next(self._steps)
            except StopIteration:
                self.done = True
                break
            if time.perf_counter() >= end:
                break
        if self._flare is None:
            from .flare import frame_flare
            made = frame_flare(self.renderer, PREVIEW_FLARE_SAMPLES)
            f = self.renderer.film
            self._flare = (False if made is None else
                           made[0].reshape(f.height, f.width, 3).astype("float32"))
        return self.done

    @property
    def samples_done(self) -> int:
        return 0 if self.renderer is None else self.renderer.stats.samples_done

    def image(self):
        """(H, W, 4) float32 Combined so far, row 0 at the bottom; None before any update."""
        if self.renderer is None:
            return None
        image = self.renderer.film.image("Combined")
        if self._flare is not None and self._flare is not False:
            image = image.copy()
            image[..., :3] += self._flare
        return image

    def close(self) -> None:
        if self._materials is not None:
            self._materials.close()
        self.renderer, self._materials, self._steps, self.key = None, None, None, None
