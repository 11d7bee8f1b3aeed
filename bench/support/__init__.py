"""Harness shared by the benchmarks and the tests: a local S3 server, fuzz mutations, lock races,
the cache read floor. Dev-only (moto); the product never imports it."""
