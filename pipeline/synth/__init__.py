"""Synthetic GrandTour recordings (procedural scenes, ground truth, injected faults).

Public API: `synthesize`, `synthesize_all`, `SynthResult` (pipeline.synth.api). Layout: FORMAT.md.
"""
