"""The authors' own figures on the 3F2N sample frames, shipped as data.

``official-3f2n-sample.json`` holds e_A per frame (and ms per frame) of the
authors' implementations (d2nt 0.1.3 from PyPI, 3F2N and SDA-SNE from the
SDA-SNE authors' demo) on the 12 frames of the 3F2N sample.
"""

from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path

__all__ = ["official_figures", "OFFICIAL_KEYS"]

# surfnorm method name -> key in the JSON
OFFICIAL_KEYS = {
    "d2nt_basic": "official_d2nt_basic",
    "d2nt_v2": "official_d2nt_v2",
    "d2nt_v3": "official_d2nt_v3",
    "3f2n_mean": "official_3f2n_mean",
    "3f2n_median": "official_3f2n_median",
    "sda_sne": "official_sda_sne_3iter",
    # not a method name: sda_sne with iterations=None (run until stable)
    "sda_sne_converged": "official_sda_sne_converged",
}


@lru_cache(maxsize=1)
def _load() -> dict:
    path = Path(__file__).resolve().parent / "data" / "official-3f2n-sample.json"
    return json.loads(path.read_text())["frames"]


def official_figures(frame: str) -> dict[str, float]:
    """e_A of the authors' implementations on ``frame`` (e.g. ``Easy/android/000001``), by surfnorm method name.

    ``"sda_sne_converged"`` is ``sda_sne`` with ``iterations=None``.
    """
    row = _load().get(frame, {})
    return {name: row[key] for name, key in OFFICIAL_KEYS.items() if key in row}
