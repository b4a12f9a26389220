"""Import a repository file that is not part of the package (a benchmark, a script, an example) as a module.

Shared by the tests that check such files' functions directly. The module is registered in `sys.modules`
under `name` before it runs, as a dataclass defined in it needs."""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

ROOT = Path(__file__).resolve().parents[1]


def load_file_module(path: Path, name: str) -> ModuleType:
    """Run `path` (absolute, or relative to the repository root) as module `name`, freshly, and return it."""
    spec = importlib.util.spec_from_file_location(name, ROOT / path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module
