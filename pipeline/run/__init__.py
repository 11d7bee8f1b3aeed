"""Execution of the stage graph: stage contract, locking, executors, resumption."""
