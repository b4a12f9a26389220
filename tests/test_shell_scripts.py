"""Every shell script the project ships parses (`bash -n`): the GPU run scripts are only exercised on a lent
device or by their CPU smoke tests (each script's header), so a syntax slip would otherwise surface there."""
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = sorted(p for folder in ("scripts", "benchmarks", ".ci") for p in (ROOT / folder).rglob("*.sh"))


def test_scripts_are_found():
    names = {p.name for p in SCRIPTS}
    assert {"gpu_train_default.sh", "gpu_two_stage.sh", "gpu_train_chain.sh", "run_steps.sh"} <= names


@pytest.mark.skipif(shutil.which("bash") is None, reason="no bash")
@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: str(p.relative_to(ROOT)))
def test_script_parses(script: Path):
    done = subprocess.run(["bash", "-n", str(script)], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
