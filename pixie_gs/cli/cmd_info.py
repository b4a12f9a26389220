"""`pixie info IN`: what a splat file holds (any format pixie-gs reads, detected by content)."""
from __future__ import annotations

import argparse
import json

import numpy as np

from ..materials import MATERIAL_NAMES
from ..splat import read_splat_valid
from .options import add_drop_invalid_option


def add_parser(sub: argparse._SubParsersAction, parents: list) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "info", parents=parents, help="count, bounds, SH degree, properties, material statistics",
        description="Print what a splat file holds: its format (found by content: INRIA 3DGS .ply, SuperSplat "
        "compressed .ply, .splat or .spz), count, bounds, SH degree, properties and materials.",
        epilog="example: pixie info scene.ply",
    )
    p.add_argument("input", metavar="IN", help="3D Gaussian splat file (.ply, .compressed.ply, .splat, .spz)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    add_drop_invalid_option(p)
    p.set_defaults(func=run)
    return p


def summarize(path: str, drop_invalid: bool = False) -> dict:
    """A JSON-ready summary of the splat at `path`."""
    cloud = read_splat_valid(path, drop_invalid)
    lo, hi = cloud.bounds()
    info: dict = {
        "file": path,
        "format": cloud.source_format,
        "count": len(cloud),
        "bounds_min": [round(float(v), 6) for v in lo],
        "bounds_max": [round(float(v), 6) for v in hi],
        "sh_degree": cloud.sh_degree,
        "properties": list(cloud.property_order),
    }
    if cloud.has_materials():
        mid, E, nu, rho = cloud.get_materials()
        classes = {}
        for m in np.unique(mid):
            sel = mid == m
            classes[MATERIAL_NAMES.get(int(m), str(int(m)))] = {
                "count": int(sel.sum()),
                "E_median_pa": float(np.median(E[sel])),
                "nu_median": float(np.median(nu[sel])),
                "density_median_kg_m3": float(np.median(rho[sel])),
            }
        info["materials"] = classes
    return info


def run(args: argparse.Namespace) -> int:
    info = summarize(args.input, args.drop_invalid)
    if args.json:
        print(json.dumps(info))
        return 0
    from ..formats import LABELS

    print(f"file        {info['file']}")
    print(f"format      {LABELS.get(info['format'], info['format'])}")
    print(f"gaussians   {info['count']}")
    print(f"bounds      min {info['bounds_min']}  max {info['bounds_max']}")
    print(f"sh degree   {info['sh_degree']}")
    print(f"properties  {len(info['properties'])}: {' '.join(info['properties'])}")
    for name, s in info.get("materials", {}).items():
        print(f"material    {name:<13} {s['count']:>9} gaussians  E {s['E_median_pa']:.3g} Pa  "
              f"nu {s['nu_median']:.3f}  density {s['density_median_kg_m3']:.4g} kg/m3")
    return 0
