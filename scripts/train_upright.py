"""Retrain the upright scorer (pixie_gs/data/upright_scorer.json) used by pixie_gs/prepare/upright.py.

Objects of every class from the dataset's TRAIN seeds (object_seed(SEED, "train", i)), 4,000–20,000
Gaussians, each turned by a random rotation, go through the same steps as `prepare` (floater
mask, robust spacing) and give their up candidates and descriptors (shape, colour contrast of the ends); a candidate within 10°
of the true up (the rotation applied to +z) or of one of the generator's equal-law ups (a stack of
books upside down, a frame turned a quarter in its plane: as likely a draw as the built pose, so
teaching only the built one teaches a coin toss) is a right answer, and for an object with none
that close (a duck on its round bottom) its nearest candidate within 20° of the truth.
Objects the generator laid off their base (a can or bottle on its side: a quarter of cans, a fifth
of bottles) are left out of the fit: their shape alone cannot say they are not standing, and
teaching both makes every tall cylinder a coin toss. `--members` one-hidden-layer perceptrons
(seeds 0, 1, …) are fitted so that the right candidates of each object win the softmax over its
candidates (listwise cross-entropy, full-batch Adam, weight decay); the scorer is their mean. The
VAL seeds report the held-out accuracy; the TEST seeds (benchmarks/bench_prepare.py) are never
looked at here.

usage: python scripts/train_upright.py --objects 5200 --val 520 --hidden 64 --members 4 --workers 2 [--cache /tmp/up.npz]
(about 32 minutes on the shared 2-core CPU at load average 3–5: 23 building the objects and their
descriptors, 9 fitting; --cache keeps the descriptors, so a refit skips the first part)
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))  # tests/upright_match.py

RIGHT_DEG = 10.0
NEAR_DEG = 20.0
SEED = 0


def one_object(split: str, i: int, seed: int = SEED) -> dict:
    """Object `i` of `split`: class, candidate ups (K,3), descriptors (K,F), true up (3,), its
    equal-law ups (list of (3,): tests/upright_match.equal_law_ups) and whether the generator laid
    it off its base (a can or bottle lying on its side). Its Gaussian
    count and rotation come from its own generator ([seed, split, i]), so objects can be built in
    any order or in parallel."""
    from scipy.spatial.transform import Rotation

    from pixie_gs.dataset.assemble import build_object
    from pixie_gs.dataset.generate import object_seed
    from pixie_gs.dataset.labels import load_class_table
    from pixie_gs.prepare.density import floater_mask, robust_spacing
    from pixie_gs.prepare.upright import candidates
    from upright_match import equal_law_ups

    table = load_class_table()
    names = sorted(table)
    rng = np.random.default_rng([seed, 7 if split == "train" else 8, i])
    name = names[i % len(names)]
    cloud, record = build_object(table[name], object_seed(seed, split, i), int(rng.integers(4000, 20001)))
    R = Rotation.random(random_state=rng.integers(1 << 31)).as_matrix()
    x = cloud.means.astype(np.float64) @ R.T
    cloud.means = x.astype(np.float32)
    cloud.set_covariances(R @ cloud.covariances() @ R.T)
    alpha = cloud.opacities.astype(np.float64)
    spacing = robust_spacing(x)
    keep = ~floater_mask(x, alpha, spacing)[0]
    cands = candidates(x[keep], alpha[keep], cloud.rotations[keep], cloud.log_scales[keep], spacing,
                       colours=cloud.rgb()[keep])
    return {"name": name, "ups": np.stack([c.up for c in cands]),
            "features": np.stack([c.features for c in cands]), "truth": R @ np.array([0.0, 0.0, 1.0]),
            "equal": equal_law_ups(record, R), "off_base": bool(record["shape"].get("lying"))}


def _one(args: tuple[str, int]) -> dict:
    return one_object(*args)


def object_candidates(split: str, count: int, workers: int = 1) -> list[dict]:
    """Objects 0..count-1 of `split` (one_object), on `workers` processes."""
    from pixie_gs.progress import progress

    jobs = [(split, i) for i in range(count)]
    if workers <= 1:
        return [_one(j) for j in progress(jobs, desc=f"{split} objects", unit="object")]
    import multiprocessing as mp

    with mp.get_context("spawn").Pool(workers) as pool:
        return list(progress(pool.imap(_one, jobs, chunksize=8), total=count, desc=f"{split} objects",
                             unit="object"))


def pack(objs: list[dict]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(features (B,K,F) zero-padded, candidate mask (B,K), right-answer mask (B,K)). Right: within
    RIGHT_DEG of the truth or of an equal-law up; for an object with none that close (a bush on its
    root, a duck on its round bottom: no candidate is exact), its nearest candidate to the truth
    when within NEAR_DEG."""
    k = max(len(o["ups"]) for o in objs)
    f = objs[0]["features"].shape[1]
    X = np.zeros((len(objs), k, f))
    M = np.zeros((len(objs), k), bool)
    Y = np.zeros((len(objs), k), bool)
    for i, o in enumerate(objs):
        n = len(o["ups"])
        X[i, :n], M[i, :n] = o["features"], True
        cos = o["ups"] @ o["truth"]
        Y[i, :n] = cos > np.cos(np.radians(RIGHT_DEG))
        for u in o.get("equal", []):
            Y[i, :n] |= o["ups"] @ u > np.cos(np.radians(RIGHT_DEG))
        if not Y[i].any() and cos.max() > np.cos(np.radians(NEAR_DEG)):
            Y[i, int(np.argmax(cos))] = True
    return X, M, Y


def fit(X: np.ndarray, M: np.ndarray, Y: np.ndarray, hidden: int, decay: float, epochs: int, seed: int = 0) -> dict:
    """Listwise softmax training of score(x) = w2·tanh(W1ᵀ x̂ + b1) + b2 (x̂ standardised)."""
    import torch

    torch.manual_seed(seed)
    torch.set_num_threads(1)  # a tiny model: threads only add overhead on a shared CPU
    flat = X[M]
    mean, std = flat.mean(axis=0), flat.std(axis=0) + 1e-6
    use = Y.any(axis=1)
    xt = torch.tensor((X[use] - mean) / std, dtype=torch.float32)
    mt, yt = torch.tensor(M[use]), torch.tensor(Y[use])
    net = torch.nn.Sequential(torch.nn.Linear(X.shape[2], hidden), torch.nn.Tanh(), torch.nn.Linear(hidden, 1))
    opt = torch.optim.Adam(net.parameters(), lr=0.01, weight_decay=decay)
    for _ in range(epochs):
        s = net(xt).squeeze(-1).masked_fill(~mt, -1e9)
        loss = -(torch.logsumexp(s.masked_fill(~yt, -1e9), 1) - torch.logsumexp(s, 1)).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    W1, b1 = net[0].weight.detach().numpy().T, net[0].bias.detach().numpy()
    w2, b2 = net[2].weight.detach().numpy()[0], net[2].bias.detach().numpy()[0]
    return {"mean": mean, "std": std, "W1": W1, "b1": b1, "w2": w2, "b2": float(b2), "loss": float(loss.detach())}


def evaluate(objs: list[dict], model: dict) -> np.ndarray:
    """Angle (degrees) between the winning candidate and the truth or its nearest equal-law up, per
    object."""
    from pixie_gs.prepare.upright import score

    errs = []
    for o in objs:
        best = o["ups"][int(np.argmax(score(o["features"], model)))]
        errs.append(min(np.degrees(np.arccos(np.clip(best @ u, -1, 1))) for u in [o["truth"], *o.get("equal", [])]))
    return np.array(errs)


def _load_or_build(cache: Path | None, split: str, count: int, workers: int = 1) -> list[dict]:
    path = None if cache is None else cache.with_name(f"{cache.stem}_{split}{count}.npz")
    if path is not None and path.exists():
        data = np.load(path, allow_pickle=True)
        return list(data["objs"])
    objs = object_candidates(split, count, workers)
    if path is not None:
        np.savez(path, objs=np.array(objs, dtype=object))
    return objs


def ensemble(members: list[dict]) -> dict:
    """One scorer of several fitted members (same standardisation): W1 (E,F,H), b1 (E,H), w2 (E,H),
    b2 (E,), weights rounded to 5 significant digits (upright.score averages the members)."""
    def r(v) -> np.ndarray:
        return np.asarray([float(f"{x:.5g}") for x in np.ravel(v)]).reshape(np.shape(v))

    return {"mean": r(members[0]["mean"]), "std": r(members[0]["std"]),
            **{k: r(np.stack([np.asarray(m[k]) for m in members])) for k in ("W1", "b1", "w2", "b2")}}


def main() -> int:
    from pixie_gs.prepare.upright import FEATURES, WEIGHTS

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--objects", type=int, default=5200)
    ap.add_argument("--val", type=int, default=520)
    ap.add_argument("--hidden", type=int, default=64)
    ap.add_argument("--members", type=int, default=4, help="perceptrons fitted from seeds 0.. and averaged")
    ap.add_argument("--decay", type=float, default=1e-3)
    ap.add_argument("--epochs", type=int, default=600)
    ap.add_argument("--workers", type=int, default=1, help="processes building the objects")
    ap.add_argument("--cache", default=None, help="reuse/save descriptors here (e.g. /tmp/upright.npz)")
    ap.add_argument("--out", default=str(WEIGHTS))
    args = ap.parse_args()
    cache = Path(args.cache) if args.cache else None
    t0 = time.perf_counter()
    train = _load_or_build(cache, "train", args.objects, args.workers)
    val = _load_or_build(cache, "val", args.val, args.workers)
    built = time.perf_counter() - t0
    kept = [o for o in train if not o["off_base"]]
    X, M, Y = pack(kept)
    recall = float(Y.any(axis=1).mean())
    model = ensemble([fit(X, M, Y, args.hidden, args.decay, args.epochs, seed) for seed in range(args.members)])
    tr, va = evaluate(train, model), evaluate(val, model)
    print(f"trained on {len(kept)} of {len(train)} objects (the rest lie off their base); "
          f"candidates: {M.sum(1).mean():.1f} per object; a right one (≤ {RIGHT_DEG:.0f}°, else the "
          f"nearest if ≤ {NEAR_DEG:.0f}°) among them for {recall * 100:.0f} % of them")
    for label, e in (("train", tr), ("val", va)):
        print(f"{label}: {len(e)} objects, median {np.median(e):.1f}°, ≤ 20° on {np.mean(e <= 20) * 100:.0f} %, "
              f"worst {e.max():.1f}°")
    names = sorted({o["name"] for o in val})
    for name in names:
        v = np.array([e for o, e in zip(val, va) if o["name"] == name])
        print(f"  val {name:18s} median {np.median(v):6.1f}°  ≤ 20° on {np.mean(v <= 20) * 100:3.0f} %  "
              f"worst {v.max():6.1f}°")
    record = {"features": list(FEATURES), **{k: np.asarray(v).tolist() for k, v in model.items()},
              "made_by": f"python scripts/train_upright.py --objects {args.objects} --val {args.val} "
                         f"--hidden {args.hidden} --members {args.members} --decay {args.decay} "
                         f"--epochs {args.epochs}",
              "train_seeds": f"object_seed({SEED}, 'train', 0..{args.objects - 1}), classes round-robin, "
                               "objects laid off their base left out",
              "val_median_deg": round(float(np.median(va)), 2),
              "val_within_20_deg": round(float(np.mean(va <= 20)), 3)}
    Path(args.out).write_text(json.dumps(record) + "\n")
    print(f"wrote {args.out} (objects built in {built:.0f} s, all in {time.perf_counter() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
