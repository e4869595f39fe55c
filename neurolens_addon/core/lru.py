"""A small thread-safe LRU dict for the content-keyed caches (lenses, focus solves, pupils,
centre irradiances, ghost rankings): redraws, frame changes and both renderers repeat the same
questions, from the main thread and a render's threads at once."""

from __future__ import annotations

import threading
from collections import OrderedDict

_LOCK = threading.RLock()


class Bounded(OrderedDict):
    """The least recently used entries go once `maxsize` is exceeded."""

    def __init__(self, maxsize: int):
        super().__init__()
        self.maxsize = maxsize

    def get_lru(self, key):
        with _LOCK:
            if key in self:
                self.move_to_end(key)
                return self[key]
        return None

    def put(self, key, value):
        with _LOCK:
            self[key] = value
            self.move_to_end(key)
            while len(self) > self.maxsize:
                self.popitem(last=False)
        return value


#: every cache made here, so that clear_all() forgets them together
ALL: list[Bounded] = []


def cache(maxsize: int) -> Bounded:
    c = Bounded(maxsize)
    ALL.append(c)
    return c


def clear_all() -> None:
    with _LOCK:
        for c in ALL:
            c.clear()
