"""The fast feature field (CPU numpy/scipy, CUDA torch) against its plain twin and an independent brute force.

`splat_field` (pixie_gs/field_stencil.py) must give the numbers of `splat_field_reference` (the plain
torch stencil) and of a float64 evaluation of every Gaussian at every voxel centre written here;
CUDA must give the CPU's numbers (skipped without a GPU); a CPU annotate must leave CUDA alone.
"""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import torch

from pixie_gs.field import (cloud_tensors, feature_grid, prepare_gaussians, rotated_covariances, splat_field,
                            up_rotation)
from pixie_gs.field_reference import splat_field_reference
from pixie_gs.field_stencil import stencil_field
from pixie_gs.splat import quat_to_rotmat

CUDA = torch.cuda.is_available()
BOUNDARY_WEIGHT = float(np.exp(-4.5))  # α·exp(-½·3²): a voxel centre on the cutoff surface, per unit α


def _random_gaussians(m: int, seed: int, lo=0.05, hi=0.95, size_voxels=(0.1, 3.0), n=32, feats=5):
    """Random means in [lo, hi]³, random rotations, sizes in voxels, opacities and features (float32)."""
    rng = np.random.default_rng(seed)
    rot = quat_to_rotmat(rng.normal(size=(m, 4)))
    sd = rng.uniform(*size_voxels, (m, 3)) / n
    cov = np.einsum("nij,nj,nkj->nik", rot, sd ** 2, rot)
    t = lambda a: torch.as_tensor(a, dtype=torch.float32)  # noqa: E731
    return (t(rng.uniform(lo, hi, (m, 3))), t(cov), t(rng.uniform(0.05, 1.0, m)), t(rng.normal(size=(m, feats))))


def _assert_same_field(got, want, rel=1e-5):
    """Density and feature sums equal within float32 summation-order tolerance."""
    for g, w in zip(got, want):
        assert g.shape == w.shape
        if w.numel():
            scale = float(w.abs().max()) + 1e-12
            assert float((g - w).abs().max()) <= rel * scale + 1e-7


CASES = {
    "small Gaussians (filter-dominated)": (dict(m=3000, seed=1, size_voxels=(0.05, 1.0)), {}),
    "mixed sizes, some wider than the stencil cap": (dict(m=1500, seed=2, size_voxels=(0.1, 5.0)), {}),
    "centres outside the grid (robust-box normalisation)": (dict(m=1500, seed=3, lo=-0.2, hi=1.2), {}),
    "no pre-filter, tiny Gaussians": (dict(m=1500, seed=4, size_voxels=(0.01, 0.3)), {"filter_voxels": 0.0}),
    "small chunks": (dict(m=1500, seed=5), {"chunk_pairs": 40000}),  # fast path only (the reference is slow so)
    "wide stencil cap": (dict(m=300, seed=6, size_voxels=(1.0, 8.0)), {"max_radius_voxels": 10}),
    "no features": (dict(m=500, seed=7, feats=0), {}),
}


@pytest.mark.parametrize("case", list(CASES))
def test_fast_field_equals_the_plain_reference(case):
    make, kw = CASES[case]
    args = _random_gaussians(**make)
    ref_kw = {k: v for k, v in kw.items() if k != "chunk_pairs"}
    _assert_same_field(splat_field(*args, 32, **kw), splat_field_reference(*args, 32, **ref_kw))


@pytest.mark.parametrize("case", ["mixed sizes, some wider than the stencil cap",
                                  "centres outside the grid (robust-box normalisation)", "small chunks"])
def test_torch_path_of_the_gpu_equals_the_reference_on_cpu(case):
    """The CUDA path's torch code, run on CPU tensors here so that CI without a GPU checks it."""
    make, kw = CASES[case]
    args = _random_gaussians(**make)
    ref_kw = {k: v for k, v in kw.items() if k != "chunk_pairs"}
    got = stencil_field(*args, 32, backend="torch", **kw)
    _assert_same_field(got, splat_field_reference(*args, 32, **ref_kw))
    batch = torch.as_tensor(np.random.default_rng(0).integers(0, 2, len(args[0])))
    _assert_same_field(stencil_field(*args, 32, batch_index=batch, batch_size=2, backend="torch", **kw),
                       splat_field(*args, 32, batch_index=batch, batch_size=2, **kw))


@pytest.mark.parametrize("backend", [None, "torch"])
def test_a_nan_gaussian_adds_nothing(backend):
    """NaN centres or covariances (read_splat_valid rejects them first) add nothing, crash nothing."""
    means, cov, alphas, feats = _random_gaussians(300, 10)
    bad_means, bad_cov = means.clone(), cov.clone()
    bad_means[7] = float("nan")
    bad_cov[3] = float("nan")
    keep = torch.ones(300, dtype=torch.bool)
    keep[[3, 7]] = False
    got = stencil_field(bad_means, bad_cov, alphas, feats, 32, backend=backend)
    _assert_same_field(got, splat_field(means[keep], cov[keep], alphas[keep], feats[keep], 32))


@pytest.mark.parametrize("path", ["numpy", "torch", "reference"])
def test_a_needle_whose_float32_covariance_is_not_positive_definite_adds_at_most_its_alpha(path):
    """A needle ~300 grid sides long and 1/50 of one wide (σ ratio 1.6e4; a mutated .spz had one and annotate
    ended in NaN): in float32 its covariance has a negative eigenvalue larger than the 0.5-voxel filter, so the
    quadratic form goes negative and exp(-½ maha) reached 1e25. Every path must keep each Gaussian's weight
    at a voxel within its α, so the density never exceeds the sum of the opacities."""
    means, cov, alphas, feats = _random_gaussians(50, 11)
    rot = quat_to_rotmat(np.array([[0.13, -0.13, 0.64, 0.1]]))[0]  # one whose float32 rounding is not PD
    needle = (rot @ np.diag(np.array([300.0, 0.02, 0.02]) ** 2) @ rot.T).astype(np.float32)
    n = 32
    assert np.linalg.eigvalsh(needle.astype(np.float64) + (0.5 / n) ** 2 * np.eye(3)).min() < 0
    cov = torch.cat([cov, torch.as_tensor(needle)[None]])
    means = torch.cat([means, torch.tensor([[0.5, 0.5, 0.5]])])
    alphas = torch.cat([alphas, torch.tensor([0.8])])
    feats = torch.cat([feats, torch.ones(1, feats.shape[1])])
    if path == "reference":
        dens, sums = splat_field_reference(means, cov, alphas, feats, n)
    else:
        dens, sums = stencil_field(means, cov, alphas, feats, n, backend=None if path == "numpy" else "torch")
    assert torch.isfinite(dens).all() and torch.isfinite(sums).all()
    assert float(dens.max()) <= float(alphas.sum()) * (1 + 1e-6)


def test_fast_field_batches_like_separate_grids():
    """batch_index puts Gaussians into their own grid: the same as the reference and as one grid each."""
    args = _random_gaussians(2400, 8)
    batch = torch.as_tensor(np.random.default_rng(8).integers(0, 3, 2400))
    got = splat_field(*args, 24, batch_index=batch, batch_size=3)
    _assert_same_field(got, splat_field_reference(*args, 24, batch_index=batch, batch_size=3))
    for b in range(3):
        sel = batch == b
        alone = splat_field(*(a[sel] for a in args), 24)
        _assert_same_field((got[0][b:b + 1], got[1][b:b + 1]), alone)


def test_fast_field_equals_an_independent_float64_brute_force():
    """Every Gaussian evaluated at every voxel centre in float64 (no stencil, no grouping); sizes
    keep every cutoff ellipsoid inside the stencil cap (reach ≤ 3·√(1.5² + 0.5²) ≈ 4.7 voxels)."""
    n = 16
    means, cov, alphas, feats = _random_gaussians(200, 9, lo=0.1, hi=0.9, size_voxels=(0.2, 1.5), n=n, feats=2)
    dens, sums = splat_field(means, cov, alphas, feats, n)
    c = (np.arange(n) + 0.5) / n
    x = np.stack(np.meshgrid(c, c, c, indexing="ij"), -1).reshape(-1, 3)
    prec = np.linalg.inv(cov.double().numpy() + (0.5 / n) ** 2 * np.eye(3))
    d = x[None] - means.double().numpy()[:, None]
    maha = np.einsum("gvi,gij,gvj->gv", d, prec, d)
    w = alphas.double().numpy()[:, None] * np.exp(-0.5 * maha) * (maha <= 9.0)
    want_d, want_s = w.sum(0), w.T @ feats.double().numpy()
    # a voxel centre within float32 rounding of a cutoff surface may count on one side only
    off = np.abs(dens[0].double().numpy() - want_d) > 1e-5 * want_d.max()
    assert off.mean() < 1e-3
    assert np.abs(dens[0].double().numpy() - want_d).max() <= BOUNDARY_WEIGHT + 1e-5
    assert np.allclose(sums[0].double().numpy()[~off], want_s[~off], rtol=1e-5, atol=1e-5 * np.abs(want_s).max())


def _generated(count: int = 20000, name: str = "tree", seed: int = 3):
    from pixie_gs.dataset.assemble import build_object
    from pixie_gs.dataset.labels import load_class_table

    return build_object(load_class_table()[name], seed, count)[0]


def test_generated_object_turned_and_boxed_matches_the_reference():
    """A generated tree turned y-up → z-up and normalised by a box smaller than the object (some
    centres leave the grid): the prepared Gaussians go through both implementations alike."""
    cloud = _generated()
    rot = up_rotation("y")
    cv = cloud.covariances()
    assert np.allclose(rotated_covariances(cloud, rot), rot @ cv @ rot.T, rtol=1e-6, atol=1e-6 * np.abs(cv).max())
    g = cloud_tensors(cloud, [], "cpu", rot)
    lo, hi = g.means.amin(0).numpy(), g.means.amax(0).numpy()
    box = (lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo))
    means, cov, alpha, feats, _, _ = prepare_gaussians(g, 0.05, box)
    assert float(means.min()) < 0.0 or float(means.max()) > 1.0
    _assert_same_field(splat_field(means, cov, alpha, feats, 64), splat_field_reference(means, cov, alpha, feats, 64))


@pytest.mark.parametrize("box", [None, ((-0.1, -0.2, 0.0), (0.2, 0.1, 0.3))])
def test_prepare_gaussians_numpy_and_torch_paths_agree(box):
    """The CPU (numpy) and CUDA (torch, run here on CPU tensors) normalisation give the same Gaussians."""
    from pixie_gs.field import _prepare_gaussians_numpy, _prepare_gaussians_torch

    g = cloud_tensors(_generated(5000, "soda_cans"), [], "cpu", up_rotation("-y"))
    got, want = _prepare_gaussians_numpy(g, 0.05, box), _prepare_gaussians_torch(g, 0.05, box)
    assert got[4] == pytest.approx(want[4], rel=1e-12)
    for a, b in zip(got[:4] + got[5:], want[:4] + want[5:]):
        assert a.shape == b.shape and a.dtype == b.dtype
        assert torch.allclose(a, b, rtol=1e-6, atol=1e-6)


def test_cpu_annotate_leaves_cuda_alone(tmp_path):
    """A CPU feature grid and U-Net pass do not initialise CUDA nor import Warp (lazy imports)."""
    code = (
        "import sys, torch\n"
        "from pixie_gs.dataset.assemble import build_object\n"
        "from pixie_gs.dataset.labels import load_class_table\n"
        "from pixie_gs.annotate import annotate_cloud\n"
        "cloud = build_object(load_class_table()['soda_cans'], 1, 3000)[0]\n"
        "annotate_cloud(cloud, device='cpu')\n"
        "print(torch.cuda.is_initialized(), 'warp' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split()[-2:] == ["False", "False"]


@pytest.mark.skipif(not CUDA, reason="needs a CUDA GPU")
@pytest.mark.parametrize("case", ["small Gaussians (filter-dominated)", "mixed sizes, some wider than the stencil cap",
                                  "centres outside the grid (robust-box normalisation)"])
def test_cuda_field_equals_cpu(case):
    make, kw = CASES[case]
    args = _random_gaussians(**make)
    cpu = splat_field(*args, 32, **kw)
    gpu = splat_field(*(a.cuda() for a in args), 32, **kw)
    assert gpu[0].device.type == "cuda"
    _assert_same_field([t.cpu() for t in gpu], cpu, rel=2e-5)
    ref = splat_field_reference(*(a.cuda() for a in args), 32, **kw)
    _assert_same_field([t.cpu() for t in gpu], [t.cpu() for t in ref], rel=2e-5)


@pytest.mark.skipif(not CUDA, reason="needs a CUDA GPU")
def test_cuda_feature_grid_equals_cpu():
    """The whole grid of a 200k-Gaussian generated tree: CUDA and CPU agree (voxels on a cutoff
    surface aside, which float rounding may put on either side)."""
    cloud = _generated(200000)
    cpu = feature_grid(cloud, 64, [], device="cpu", up="y")
    gpu = feature_grid(cloud, 64, [], device="cuda", up="y")
    d_cpu, d_gpu = cpu.extra["density"], gpu.extra["density"]
    diff = np.abs(d_cpu - d_gpu)
    assert diff.max() <= BOUNDARY_WEIGHT + 1e-4 * d_cpu.max()
    assert (diff > 1e-4 * d_cpu.max()).mean() < 1e-3
    assert (cpu.occupancy == gpu.occupancy).mean() > 0.999
    same = (diff <= 1e-5 * d_cpu.max()) & cpu.occupancy
    assert np.allclose(cpu.values[:, same], gpu.values[:, same], rtol=1e-3, atol=1e-3)


@pytest.mark.skipif(not CUDA, reason="needs a CUDA GPU")
def test_cuda_field_gives_the_same_bytes_every_run():
    """The CUDA sums add in a sorted order (`add_rows_in_order`), so annotating a splat twice on a GPU
    writes the same file (float atomics gave other last bits each run); torch's process-wide
    deterministic mode is left off (other model threads of a batch would run in it)."""
    cloud = _generated(200000)
    first = feature_grid(cloud, 64, [], device="cuda", up="y")
    for _ in range(2):
        again = feature_grid(cloud, 64, [], device="cuda", up="y")
        assert again.values.tobytes() == first.values.tobytes()
    assert not torch.are_deterministic_algorithms_enabled()


def test_ordered_row_sums_equal_index_add_with_repeated_targets():
    """`add_rows_in_order` (index_put_ with accumulate on CUDA, index_add_ elsewhere) adds whole rows,
    repeated targets included; the CUDA call's semantics checked on CPU tensors against index_add_."""
    from pixie_gs.field_stencil import add_rows_in_order

    g = torch.Generator().manual_seed(0)
    index = torch.randint(0, 50, (4000,), generator=g)  # ~80 rows per target
    values = torch.rand(4000, 5, generator=g)
    want = torch.zeros(50, 5).index_add_(0, index, values)
    got = torch.zeros(50, 5)
    add_rows_in_order(got, index, values)
    assert torch.equal(got, want)
    put = torch.zeros(50, 5)
    put.index_put_((index,), values, accumulate=True)  # the CUDA branch's call
    assert torch.allclose(put, want, rtol=1e-5, atol=1e-5)
    assert not torch.are_deterministic_algorithms_enabled()
