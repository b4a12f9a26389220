"""pixie_gs/prefetch.py: background imports (used to hide scipy/matplotlib import time in diagnose)."""
from __future__ import annotations


def test_prefetch_imports_in_the_background_and_ignores_bad_names():
    import sys

    from pixie_gs import prefetch as pf

    name = "json.tool"  # small and stdlib; imported by nothing else in the test run
    sys.modules.pop(name, None)
    pf.prefetch("no_such_module_xyz", name)
    assert pf.wait(30.0)
    assert name in sys.modules and "no_such_module_xyz" not in sys.modules
