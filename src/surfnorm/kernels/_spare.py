"""Working arrays kept from one frame for the next of the same size.

A large array allocated new for every frame has its pages mapped in afresh by the system
each time (zeroed, one fault per 4 KiB page), and on several threads the allocator tends to
return it to the system after almost every frame: on a 480x640 frame that is milliseconds of
a call that should take a few. A :class:`Spares` keeps the latest working arrays, by shape,
up to a byte budget, for the next call to take; ``release()`` lets them go.
"""

from __future__ import annotations

import threading


class Spares:
    """Spare working sets (tuples of arrays) by key, at most ``keep_bytes`` in all.

    ``take(key)`` hands one out (it is the caller's alone until it gives it back) or None;
    ``give(key, arrays)`` keeps it for the next call. Thread-safe: two calls at once each get
    their own set.
    """

    def __init__(self, keep_bytes: int):
        self.keep_bytes = keep_bytes
        self._sets: dict = {}
        self._lock = threading.Lock()

    def take(self, key):
        with self._lock:
            sets = self._sets.get(key)
            return sets.pop() if sets else None

    def give(self, key, arrays) -> None:
        nbytes = sum(a.nbytes for a in arrays)
        with self._lock:
            kept = sum(a.nbytes for sets in self._sets.values() for arrays_ in sets for a in arrays_)
            if kept + nbytes > self.keep_bytes:
                self._sets.clear()
            if nbytes <= self.keep_bytes:
                self._sets.setdefault(key, []).append(tuple(arrays))

    def release(self) -> None:
        with self._lock:
            self._sets.clear()
