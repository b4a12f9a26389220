"""Every `pixie` command: `--help` works fast (exit 0, an example, no torch/warp/rerun/trimesh
import) and a bad argument gives one error line, no traceback, a non-zero exit and no output.

Commands run as a user runs them, `python -m pixie_gs ...`, in subprocesses.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from pixie_gs.cli.main import COMMANDS

HEAVY_MODULES = ("torch", "warp", "rerun", "trimesh")
REGISTERED = [c for c in COMMANDS if (Path(__file__).resolve().parent.parent / "pixie_gs" / "cli" / f"cmd_{c}.py").exists()]

# one bad argument per command: (arguments, expected exit code, a word the error must contain)
BAD_ARGUMENTS = {
    "demo": (["--frames", "1"], 1, "--frames"),
    "info": (["missing.ply"], 1, "missing.ply"),
    "convert": (["missing.obj", "out.ply"], 1, "missing.obj"),
    "generate": (["gen_out", "--count", "0"], 1, "--count"),
    "train": (["missing_dir", "--out", "model.pt"], 1, "missing_dir"),
    "evaluate": (["missing.pt", "missing_dir"], 1, "missing.pt"),
    "prepare": (["missing.ply", "out.ply"], 1, "missing.ply"),
    "annotate": (["missing.ply", "out.ply"], 1, "missing.ply"),
    "simulate": (["missing.ply", "--out", "frames"], 1, "missing.ply"),
    "render": (["missing.ply", "--out", "picture.png"], 1, "missing.ply"),
    "diagnose": (["missing.ply", "missing.npz", "--scene", "missing.json", "--out", "diag"], 1, "missing.ply"),
}


def pixie(args: list[str], cwd: Path, *python_flags: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *python_flags, "-m", "pixie_gs", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=120)


def error_lines(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if "error" in line.lower()]


def test_every_command_is_registered_and_has_a_bad_argument_case():
    assert "demo" in REGISTERED and "info" in REGISTERED
    assert set(REGISTERED) <= set(BAD_ARGUMENTS), "add a bad-argument case for every command"


@pytest.mark.parametrize("command", REGISTERED)
def test_help_has_example_and_imports_nothing_heavy(command, tmp_path):
    result = pixie([command, "--help"], tmp_path, "-X", "importtime")
    assert result.returncode == 0, result.stderr
    assert "example:" in result.stdout
    assert f"pixie {command}" in result.stdout  # the usage line names the command
    imported = {line.rsplit("|", 1)[-1].strip() for line in result.stderr.splitlines() if line.startswith("import time:")}
    assert not imported & set(HEAVY_MODULES), f"--help imported {sorted(imported & set(HEAVY_MODULES))}"


@pytest.mark.parametrize("command", REGISTERED)
def test_bad_argument_is_one_line_error_without_traceback(command, tmp_path):
    args, code, word = BAD_ARGUMENTS[command]
    result = pixie([command, *args], tmp_path)
    assert result.returncode == code, result.stderr
    assert "Traceback" not in result.stderr and "Traceback" not in result.stdout
    errors = error_lines(result.stderr)
    assert len(errors) == 1, result.stderr
    assert errors[0].startswith(f"pixie {command}: error:") and word in errors[0]
    assert list(tmp_path.iterdir()) == []  # nothing written


@pytest.mark.parametrize("command", REGISTERED)
def test_unknown_flag_is_a_usage_error(command, tmp_path):
    result = pixie([command, "--no-such-flag"], tmp_path)
    assert result.returncode == 2
    assert "Traceback" not in result.stderr
    assert len(error_lines(result.stderr)) == 1, result.stderr


def test_no_command_prints_help_and_exits_2(tmp_path):
    result = pixie([], tmp_path)
    assert result.returncode == 2
    assert "demo" in result.stdout and "Exit codes" in result.stdout


CAN_PLY = Path(__file__).resolve().parent.parent / "pixie_gs" / "data" / "examples" / "can.ply"


def probe_last_line(probe: str, args: list[str], cwd: Path, env: dict | None = None) -> str:
    """The last line a `python -c probe ARGS` process prints (it must exit 0)."""
    out = subprocess.run([sys.executable, "-c", probe, *args], capture_output=True, text=True, env=env,
                         cwd=cwd, check=True).stdout
    return out.strip().splitlines()[-1]


def test_thread_pool_defaults_unless_the_user_chose(tmp_path):
    """`pixie` sets OMP_WAIT_POLICY=PASSIVE and OPENBLAS_NUM_THREADS=1 before numpy or torch loads its
    thread pools (spinning threads steal the time slices their partners need on a busy machine); a
    value the user set is kept."""
    probe = ("import os, sys; from pixie_gs.cli.main import main; main(['info', sys.argv[1]]); "
             "import numpy, torch; print(os.environ.get('OMP_WAIT_POLICY'), os.environ.get('OPENBLAS_NUM_THREADS'))")
    ply = CAN_PLY
    for preset, want in (({}, "PASSIVE 1"), ({"OMP_WAIT_POLICY": "ACTIVE", "OPENBLAS_NUM_THREADS": "2"}, "ACTIVE 2")):
        env = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY", "OPENBLAS_NUM_THREADS")} | preset
        assert probe_last_line(probe, [str(ply)], tmp_path, env) == want


def test_only_the_pixie_process_skips_its_final_collection(tmp_path):
    """`main()` run as the process (no argv given) freezes gc at exit (the last collections walked every
    torch object: ~0.5 s); `main([...])` called by another program leaves the caller's gc alone."""
    ply = CAN_PLY
    probe = ("import atexit, gc, sys\n"
             "atexit.register(lambda: print('frozen', gc.get_freeze_count() > 0))\n"
             "from pixie_gs.cli.main import main\n"
             "if sys.argv[2] == 'process':\n"
             "    sys.argv = ['pixie', 'info', sys.argv[1]]\n"
             "    main()\n"
             "else:\n"
             "    main(['info', sys.argv[1]])\n")
    for how, want in (("process", "frozen True"), ("caller", "frozen False")):
        assert probe_last_line(probe, [str(ply), how], tmp_path) == want


def test_torch_is_imported_without_garbage_collections(tmp_path):
    """`devices.import_torch` pauses the cyclic collector while torch loads (a plain `import torch` runs
    ~365 collections, two of them full: ~0.1 s that frees little) and leaves the collector as it found
    it. Where torch's modules have no cached bytecode, compiling their source may still run a young
    collection or two with the collector paused (a fresh install with PYTHONDONTWRITEBYTECODE), so the
    test allows two young ones and no full one."""
    probe = ("import gc, sys\n"
             "runs = []\n"
             "gc.callbacks.append(lambda phase, info: runs.append(info['generation']) if phase == 'start' else None)\n"
             "if sys.argv[1] == 'off':\n"
             "    gc.disable()\n"
             "from pixie_gs.devices import import_torch\n"
             "torch = import_torch()\n"
             "seen = list(runs)\n"
             "print(torch.__name__, gc.isenabled(), len(seen) <= 2 and 2 not in seen, import_torch() is torch)\n")
    for state, want in (("on", "torch True True True"), ("off", "torch False True True")):
        assert probe_last_line(probe, [state], tmp_path) == want


def test_interrupt_raised_inside_exec_of_a_string_still_exits_130(tmp_path):
    """CPython 3.11 takes a KeyboardInterrupt raised in code that `exec` of a string runs (dataclass and
    namedtuple creation while torch imports: where a Ctrl-C often lands) for an unhandled one even when it
    is caught; a process started with `-m`, as `python -m pixie_gs` is, then kills itself with SIGINT at
    exit (-2). It must still end with its one line and exit 130. The interrupt is raised in place of a
    timed signal, so this is exact (without the fix: -2)."""
    (tmp_path / "interrupted_probe.py").write_text(
        "import argparse, sys\n"
        "import pixie_gs.cli.main as cli\n"
        "def run(args):\n"
        "    exec('raise KeyboardInterrupt')\n"
        "def build_parser():\n"
        "    parser = argparse.ArgumentParser(prog='pixie')\n"
        "    parser.add_subparsers(dest='command').add_parser('probe').set_defaults(func=run)\n"
        "    return parser\n"
        "cli.build_parser = build_parser\n"
        "sys.argv = ['pixie', 'probe']\n"
        "sys.exit(cli.main())\n")
    res = subprocess.run([sys.executable, "-m", "interrupted_probe"], capture_output=True, text=True, cwd=tmp_path,
                         timeout=120)
    assert (res.returncode, res.stderr) == (130, "pixie probe: interrupted\n")


def test_annotate_process_exits_at_once_after_flushing_and_atexit(tmp_path):
    """A single-file `pixie annotate` process ends with `os._exit` (no interpreter teardown) only after
    its output is complete, every atexit callback has run and its buffered stdout is flushed."""
    ply = CAN_PLY
    probe = ("import atexit, sys\n"
             "atexit.register(lambda: print('atexit ran'))\n"
             "import pixie_gs.cli.main as cli\n"
             "real_exit = cli.exit_at_once\n"
             "cli.exit_at_once = lambda code: (print('exiting at once', code), real_exit(code))\n"
             "sys.argv = ['pixie', 'annotate', sys.argv[1], sys.argv[2], '--device', 'cpu']\n"
             "sys.exit(cli.main())\n")
    out = tmp_path / "o.ply"
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}  # block-buffered stdout, as usual
    res = subprocess.run([sys.executable, "-c", probe, str(ply), str(out)], capture_output=True, text=True,
                         cwd=tmp_path, timeout=600, env=env)
    assert res.returncode == 0, res.stderr
    lines = res.stdout.splitlines()
    assert lines[-2:] == ["exiting at once 0", "atexit ran"] and any("gaussians" in ln for ln in lines)
    from pixie_gs.splat import read_splat

    assert len(read_splat(out)) == 11733 and read_splat(out).has("confidence")
