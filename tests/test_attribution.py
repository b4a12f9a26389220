"""First-order data attribution (pixie_gs/model/attribution.py) on the shipped network.

What must hold: the cosine's sign follows the label the test writes (an object relabelled far above what the
network reads pulls its own reading up, relabelled far below pulls it down), and the first-order change it
stands for is the one a small plain gradient step really makes (finite difference).
"""
from __future__ import annotations

import numpy as np
import pytest
import torch

from pixie_gs.dataset.assemble import build_object
from pixie_gs.dataset.generate import object_seed
from pixie_gs.dataset.labels import load_class_table
from pixie_gs.model.attribution import loss_gradient, reading_gradient, step_cosine
from pixie_gs.model.checkpoint import load_checkpoint
from pixie_gs.model.data import DeviceStore, record_from_cloud


@pytest.fixture(scope="module")
def bread():
    cloud, _ = build_object(load_class_table()["bread"], object_seed(31, "test", 0), 3000)
    return cloud


def _relabelled(cloud, E_pa: float):
    out = cloud.copy()
    mid, _, nu, rho = out.get_materials()
    out.set_materials(mid, np.full(len(out), E_pa, np.float32), nu, rho)
    return out


def _store(cloud, loaded):
    return DeviceStore([record_from_cloud(cloud, list(loaded.features.extra_names))], "cpu")


@pytest.mark.parametrize("E_pa,sign", [(5e10, +1), (2e3, -1)])
def test_an_object_labelled_stiffer_pulls_its_own_reading_up(bread, E_pa, sign):
    """Bread reads near 1e4–3e5 Pa; labelled 5e10 Pa, a step on it raises its log E reading (cosine > 0);
    labelled 2e3 Pa, it lowers it."""
    loaded = load_checkpoint(None, "cpu")
    _, grad_r = reading_gradient(loaded, bread, "z", np.ones(len(bread), bool), "log_E")
    g = loss_gradient(loaded, _store(_relabelled(bread, E_pa), loaded), [0])
    cos = step_cosine(grad_r, g)
    assert sign * cos > 0.05, cos


def test_the_cosine_predicts_what_a_small_gradient_step_does(bread):
    """θ' = θ − η g on a relabelled object: the reading moves by −η ∇r·g to first order (within 15 %)."""
    loaded = load_checkpoint(None, "cpu")
    everything = np.ones(len(bread), bool)
    before, grad_r = reading_gradient(loaded, bread, "z", everything, "log_E")
    g = loss_gradient(loaded, _store(_relabelled(bread, 5e10), loaded), [0])
    eta = 1e-3 / float(g.norm())  # a step of length 1e-3 in weight space
    predicted = -eta * float(grad_r @ g)
    with torch.no_grad():
        offset = 0
        for p in loaded.model.parameters():
            n = p.numel()
            p -= eta * g[offset:offset + n].view_as(p)
            offset += n
    after, _ = reading_gradient(loaded, bread, "z", everything, "log_E")
    assert predicted > 0 and (after - before) == pytest.approx(predicted, rel=0.15), (after - before, predicted)


def test_a_reading_needs_gaussians_and_a_known_quantity(bread):
    loaded = load_checkpoint(None, "cpu")
    with pytest.raises(ValueError, match="no Gaussians"):
        reading_gradient(loaded, bread, "z", np.zeros(len(bread), bool), "log_E")
    with pytest.raises(ValueError, match="quantity"):
        reading_gradient(loaded, bread, "z", np.ones(len(bread), bool), "stiffness")


def test_the_attribution_script_runs_on_a_set_it_is_given(bread, tmp_path):
    """scripts/real_reading_attribution.py end to end on a one-asset stand-in for the real set (a generated
    loaf as its published file) and a two-category train split: it must keep up with bench_real_set's helpers
    (it broke silently once when their arguments changed) and write one finite cosine per object and reading."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    from pixie_gs.cli.main import main
    from pixie_gs.splat import write_splat

    root = Path(__file__).resolve().parent.parent
    real = tmp_path / "real"
    (real / "orig").mkdir(parents=True)
    write_splat(bread, real / "orig" / "loaf.ply")
    everywhere = [[-100.0, -100.0, -100.0], [100.0, 100.0, 100.0]]
    (real / "expectations.json").write_text(json.dumps([{
        "file": "loaf.ply", "up": [0.0, 0.0, 1.0], "object_box": everywhere,
        "regions": [{"region": "loaf", "box": everywhere,
                     "expect": {"class_in": [0], "density_range": [100, 700], "min_share": 0.7}}]}]))
    data = tmp_path / "data"
    assert main(["generate", str(data), "--count", "2", "--split", "train", "--gaussians", "1500",
                 "--classes", "bread,mugs", "-q"]) == 0
    out = tmp_path / "attr.json"
    done = subprocess.run([sys.executable, str(root / "scripts" / "real_reading_attribution.py"), "--real", str(real),
                           "--data", str(data), "--json", str(out)], capture_output=True, text=True, cwd=root)
    assert done.returncode == 0, done.stderr[-2000:]
    result = json.loads(out.read_text())
    assert [r["name"] for r in result["readings"]] == ["loaf: loaf (log_E)", "loaf: loaf (log_rho)"]
    assert sorted(row["category"] for row in result["objects"]) == ["bread", "mugs"]
    assert all(len(row["cos"]) == 2 and all(-1.0 <= c <= 1.0 for c in row["cos"]) for row in result["objects"])
