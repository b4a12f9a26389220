"""The per-asset steps of `pixie annotate`: read + prepare, predict, write.

The single-file command and every batch runner (local pool, Ray actors) call these same functions,
so the output of a batch for one file is byte-identical to `pixie annotate IN OUT`.
"""
from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

from ..splat import SplatCloud


@dataclass(frozen=True)
class AnnotateOptions:
    """What `pixie annotate` was asked to do to every file (picklable: sent to pool workers and Ray actors).

    up: "auto", an axis name or "x,y,z"; crop: a `--crop` spec or None; device: auto/cpu/cuda."""

    checkpoint: str | None = None
    device: str = "auto"
    up: str = "auto"
    crop: str | None = None
    no_prepare: bool = False
    drop_invalid: bool = False

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> "AnnotateOptions":
        return cls(checkpoint=args.checkpoint, device=args.device, up=args.up, crop=args.crop,
                   no_prepare=bool(getattr(args, "no_prepare", False)), drop_invalid=bool(args.drop_invalid))

    def validate(self) -> None:
        """InputError for a bad --up or --crop before any file is read."""
        from ..prepare import parse_crop, parse_up

        parse_up(self.up)
        parse_crop(self.crop)


@dataclass
class PreparedAsset:
    """One input read and prepared: the cloud as read, the cloud the model sees (with `role` and
    `object_id`) and the PreparedScene (None with --no-prepare)."""

    cloud: SplatCloud
    model_cloud: SplatCloud
    prepared: object | None

    def __getstate__(self) -> dict:
        """Pickled (sent between a batch's processes) without the model cloud's copy of the input:
        only its `role` and `object_id`, from which `__setstate__` rebuilds it."""
        if self.prepared is None or self.model_cloud is self.cloud:
            return dict(self.__dict__)
        return {"cloud": self.cloud, "prepared": self.prepared, "role": self.model_cloud.get("role"),
                "object_id": self.model_cloud.get("object_id")}

    def __setstate__(self, state: dict) -> None:
        if "model_cloud" not in state:
            from ..prepare.pipeline import with_roles

            state = {"cloud": state["cloud"], "prepared": state["prepared"],
                     "model_cloud": with_roles(state["cloud"], state["role"], state["object_id"])}
        self.__dict__.update(state)


def read_prepared(path: str | Path, opts: AnnotateOptions, announce: bool = False) -> PreparedAsset:
    """Read and validate `path`, then prepare it (floaters, up, ground, objects) unless --no-prepare.
    `announce`: print the preparation's summary line (the single-file command does; a batch does not)."""
    from ..prepare import prepare_cloud
    from ..progress import stage
    from ..splat import read_splat_valid

    cloud = read_splat_valid(path, opts.drop_invalid)
    if opts.no_prepare:
        return PreparedAsset(cloud, cloud, None)
    if announce:
        stage(f"preparing {len(cloud)} Gaussians (floaters, up, ground, objects)")
    model_cloud, scene = prepare_cloud(cloud, up=opts.up, crop=opts.crop)
    if announce:
        print(scene.summary(), flush=True)
    return PreparedAsset(cloud, model_cloud, scene)


# What both processes import: scipy.spatial (with scipy.sparse) for preparation's k-d tree and convex hull,
# the CPU field's sparse sums and the transfer's k-d tree: ~0.2 s, paid once before the fork. (The
# components' scipy.ndimage / csgraph are the worker's alone.)
SHARED_MODULES = ("scipy.spatial",)
WORKER_ENV = "PIXIE_ANNOTATE_WORKER"  # "auto" (default): when a core is idle; "1": whenever possible; "0": never


class PreparingAhead:
    """`read_prepared(path, opts, announce=True)` in a forked process while this one loads torch and the model.

    A single-file `pixie annotate` spends ~0.9 s importing torch, which reading and preparing the
    input never need: on Linux, with a core to spare, the two run side by side. The worker prints
    what `read_prepared` prints, when it does, and sends the PreparedAsset (or its error) back through
    a pipe; it never writes a file. `start` returns None (the caller reads in-process) where forking
    is unsafe or pointless (not Linux, one core, torch already imported: its thread pools must not be
    forked; --no-prepare) and, unless PIXIE_ANNOTATE_WORKER=1, when no core is idle (1-minute load
    average above the cores − 1): on a busy machine the second process only adds ~0.1–0.2 CPU s of
    copy-on-write and start-up. PIXIE_ANNOTATE_WORKER=0 never forks. If the worker dies without an
    answer, `result` reads in-process."""

    def __init__(self, pid: int, fd: int, path: str | Path, opts: AnnotateOptions) -> None:
        self.pid, self.fd, self.path, self.opts = pid, fd, path, opts

    @classmethod
    def start(cls, path: str | Path, opts: AnnotateOptions) -> "PreparingAhead | None":
        import importlib
        import os
        import sys

        mode = os.environ.get(WORKER_ENV, "auto")
        cores = len(os.sched_getaffinity(0)) if sys.platform.startswith("linux") else 1
        if cores < 2 or "torch" in sys.modules or opts.no_prepare or mode == "0":
            return None
        if mode != "1" and os.getloadavg()[0] > cores - 1:  # no idle core: one process is cheaper
            return None
        for name in SHARED_MODULES:  # imported once, before the fork: both processes use them
            importlib.import_module(name)
        sys.stdout.flush()  # nothing buffered is written twice
        sys.stderr.flush()
        read_end, write_end = os.pipe()
        try:
            pid = os.fork()
        except OSError:  # no process to spare: read here
            os.close(read_end)
            os.close(write_end)
            return None
        if pid == 0:  # the worker: never returns
            _prepare_and_send(write_end, read_end, path, opts)
        os.close(write_end)
        return cls(pid, read_end, path, opts)

    def result(self) -> PreparedAsset:
        """The worker's PreparedAsset; its error re-raised (same message and exit code as in-process)."""
        import os
        import pickle

        chunks = []
        try:
            while chunk := os.read(self.fd, 1 << 20):
                chunks.append(chunk)
            os.waitpid(self.pid, 0)  # the pipe is closed: the worker is exiting
            self.pid = None
        finally:
            self.close()
        try:
            kind, value = pickle.loads(b"".join(chunks))
        except Exception:  # noqa: BLE001 - no answer (the worker was killed or crashed): do it here
            return read_prepared(self.path, self.opts, announce=True)
        if kind == "error":
            raise value
        return value

    def close(self) -> None:
        """Stop the worker if it still runs and reap it (idempotent)."""
        import os
        import signal

        if self.fd is not None:
            os.close(self.fd)
            self.fd = None
        if self.pid is not None:  # stopped early (an error or a signal here): it has nothing left to say
            try:
                os.kill(self.pid, signal.SIGKILL)
                os.waitpid(self.pid, 0)
            except (ProcessLookupError, ChildProcessError):
                pass
            self.pid = None

    def __enter__(self) -> "PreparingAhead":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _prepare_and_send(write_end: int, read_end: int, path: str | Path, opts: AnnotateOptions) -> None:
    """The forked worker of PreparingAhead: read + prepare, pickle the outcome into the pipe, `os._exit`.

    Ctrl-C and SIGTERM end it at once (the parent reports them and cleans up); an error goes back as
    the exception itself, or as a PixieError with its message and exit code when it does not pickle."""
    import os
    import pickle
    import signal
    import sys

    try:
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        os.close(read_end)
        try:
            answer = ("ok", read_prepared(path, opts, announce=True))
        except Exception as exc:  # noqa: BLE001 - re-raised in the parent
            answer = ("error", _portable(exc))
        data = pickle.dumps(answer, protocol=pickle.HIGHEST_PROTOCOL) if answer[1] is not None else b""
        sys.stdout.flush()  # all it printed is out before the parent prints anything
        sys.stderr.flush()
        with os.fdopen(write_end, "wb") as pipe:
            pipe.write(data)
    finally:
        os._exit(0)


def _portable(exc: Exception) -> Exception | None:
    """`exc` if it survives pickling unchanged; a PixieError with its message and exit code otherwise;
    None (the parent then reads in-process and meets the error itself) for anything else."""
    import pickle

    from ..errors import ComputationError, InputError, PixieError

    try:
        back = pickle.loads(pickle.dumps(exc))
        if type(back) is type(exc) and str(back) == str(exc):
            return exc
    except Exception:  # noqa: BLE001
        pass
    if isinstance(exc, PixieError):
        return (ComputationError if exc.exit_code == 3 else InputError)(str(exc))
    return None


def predict(asset: PreparedAsset, opts: AnnotateOptions) -> SplatCloud:
    """The annotated cloud to write: with preparation, the input's properties plus the materials,
    confidence and a `pixie up` header comment; with --no-prepare, the annotated model cloud."""
    return assemble(asset, predict_grids(asset, opts))


def predict_grids(asset: PreparedAsset, opts: AnnotateOptions) -> list:
    """The model's work on one asset (field → U-Net on the device): its PartPredictions. A batch runs
    this in the process that holds the model and `assemble` in a pool worker."""
    from ..annotate import predict_parts
    from ..prepare import parse_up

    given_up = parse_up(opts.up)
    return predict_parts(asset.model_cloud, opts.checkpoint, opts.device,
                         given_up if given_up is not None else "z", prepared=asset.prepared)


def assemble(asset: PreparedAsset, parts: list) -> SplatCloud:
    """The cloud `predict` returns, from the asset and its PartPredictions (host work only: the
    nearest-voxel transfer and the output's properties)."""
    from ..annotate import materials_from_parts

    out = materials_from_parts(asset.model_cloud, parts, asset.prepared)
    if asset.prepared is not None:  # the output keeps the input's properties + materials (roles: `pixie prepare`)
        out = input_with_results(asset.cloud, out, asset.prepared.up_vector)
    return out


def write_result(out: SplatCloud, prepared, path: str | Path) -> None:
    """Write the annotated splat (atomically), then its OUT.prepare.json sidecar when prepared."""
    from ..cli.cmd_prepare import write_sidecar
    from ..splat import write_splat

    write_splat(out, path)
    write_sidecar(prepared, path)


def input_with_results(cloud: SplatCloud, annotated: SplatCloud, up_vector) -> SplatCloud:
    """The input cloud plus the materials and confidence of `annotated`, and the up vector the
    preparation used as a `pixie up X Y Z` header comment, so `pixie simulate` on this file
    turns it the same way instead of estimating up again."""
    from ..prepare.updir import DECLARED_PREFIX, declared_up

    out = cloud.copy()
    out.set_materials(*annotated.get_materials())
    if annotated.has("confidence"):
        out.set("confidence", annotated.get("confidence"))
    if declared_up(out.comments) is None:
        x, y, z = (float(v) for v in up_vector)
        out.comments = list(out.comments) + [f"{DECLARED_PREFIX} {x:.6g} {y:.6g} {z:.6g}"]
    return out
