"""Discrepancy loop of `pixie diagnose`: locate where a simulation disagrees with measured tracks,
name the missing physical effect (from the library in `effects/`), add it, show the gap shrink.

Entry points: `measured.load_measured`, `pipeline.diagnose`, `report.write_report`
(see docs/diagnose.md). Modules import Warp only when a simulation runs.
"""
