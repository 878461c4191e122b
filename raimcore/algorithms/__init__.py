"""RAIM algorithms, found through a registry (see :mod:`raimcore.algorithms.base`).

To add an algorithm: write one module that calls :func:`register`, and add its module name
to ``_MODULES`` below. Nothing else in the engine, CLI or dashboard changes.
"""

from __future__ import annotations

import importlib

from .base import AlgorithmOutput, AlgorithmSpec, EpochData, get, names, register

__all__ = ["AlgorithmOutput", "AlgorithmSpec", "EpochData", "get", "names", "register"]

# One line per algorithm module (keep one per line: parallel branches add lines here).
_MODULES = [
    "parity_fde",
    "mss_fde",
    "groupfusion_gf",
    "groupfusion_rs",
    "groupfusion_qv",
    "pf_llr",
    "ekf_nis",
]

_loaded = False


def _load_all() -> None:
    global _loaded
    if not _loaded:
        _loaded = True
        for mod in _MODULES:
            importlib.import_module(f"{__name__}.{mod}")
