"""The effect library: every module in this package (except `base`) defines ONE effect.

Adding an effect = adding one small file here that defines a module-level `EFFECT` (an
`Effect` subclass instance); `registry()` discovers it automatically.
"""
from __future__ import annotations

import importlib
import pkgutil

from .base import Effect, EffectContext, Param

__all__ = ["Effect", "EffectContext", "Param", "registry", "get_effect", "effect_names"]

_REGISTRY: dict[str, Effect] | None = None


def registry() -> dict[str, Effect]:
    """All effects by name, in a stable (file-name) order."""
    global _REGISTRY
    if _REGISTRY is None:
        found: dict[str, Effect] = {}
        for info in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
            if info.name == "base" or info.name.startswith("_"):
                continue
            module = importlib.import_module(f"{__name__}.{info.name}")
            effect = getattr(module, "EFFECT", None)
            if isinstance(effect, Effect):
                if effect.name in found:
                    raise RuntimeError(f"two effects are named {effect.name!r}")
                found[effect.name] = effect
        _REGISTRY = found
    return _REGISTRY


def effect_names() -> list[str]:
    return list(registry())


def get_effect(name: str) -> Effect:
    from ...errors import InputError

    effects = registry()
    if name not in effects:
        raise InputError(f"unknown effect '{name}' (known: {', '.join(effects)})")
    return effects[name]
