"""RAIM algorithms, found through a registry (see :mod:`raimcore.algorithms.base`).

Each algorithm's array kernel sits beside its adapter: ``parity`` (kernel) and
``parity_fde`` (the registered algorithm), ``mss`` and ``mss_fde``, ``pf`` and ``pf_llr``,
``ekf`` and ``ekf_nis``, ``groupfusion`` and ``groupfusion_gf`` / ``_rs`` / ``_qv``,
the package :mod:`raimcore.araim` and ``araim``.

To add an algorithm: write one module that declares its options once
(:func:`raimcore.schema.option`) and calls :func:`register`, and add its module name to
``_MODULES`` below. Nothing else in the engine, CLI or dashboard changes. A module that
fails to import does not take the others down: they stay registered and :func:`failed`
names the failure (``raim list`` prints it).
"""

from __future__ import annotations

import importlib
import threading

from .base import AlgorithmOutput, AlgorithmSpec, get, names, register

__all__ = ["AlgorithmOutput", "AlgorithmSpec", "get", "names", "register", "failed"]

# One line per algorithm module (keep one per line: parallel branches add lines here).
_MODULES = [
    "parity_fde",
    "mss_fde",
    "groupfusion_gf",
    "groupfusion_rs",
    "groupfusion_qv",
    "pf_llr",
    "ekf_nis",
    "araim",
]

_lock = threading.Lock()
_loaded = False
_failed: dict[str, str] = {}


def _load_all() -> None:
    """Import every algorithm module once; a failing module is recorded, not raised."""
    global _loaded
    if _loaded:
        return
    with _lock:
        if _loaded:
            return
        for mod in _MODULES:
            try:
                importlib.import_module(f"{__name__}.{mod}")
            except Exception as exc:  # noqa: BLE001 - one broken module must not hide the rest
                _failed[mod] = f"{type(exc).__name__}: {exc}"
        _loaded = True


def failed() -> dict[str, str]:
    """Algorithm modules that failed to import: module name -> the error."""
    _load_all()
    return dict(_failed)
