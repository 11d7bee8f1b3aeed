"""Plausibility checks, stamp gates, damage and rejects: what ingest refuses, and why,
for every source."""
