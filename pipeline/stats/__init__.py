"""Packet statistics: per-shard rows, exact merges, DuckDB queries and canned reports."""
